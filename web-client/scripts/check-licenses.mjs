#!/usr/bin/env node
// Licence check of the web client's npm dependencies: every package in package-lock.json (and,
// when node_modules is installed, every package found there) must carry an SPDX licence
// expression that the allow-list below satisfies. It prints a summary per licence and exits
// non-zero on any package outside the allow-list, on a package without a licence, and on an
// installed package whose package.json disagrees with the lockfile or that the lockfile lacks.
//
//   node scripts/check-licenses.mjs [DIR]       check DIR (default: the web-client folder)
//   node scripts/check-licenses.mjs --self-test plant a disallowed licence in a temporary
//                                               fixture and fail unless the check catches it
//
// No dependencies: the lockfile (lockfileVersion 2 or 3, npm 7 and later) names every package
// with its path and licence, and each installed package.json says the same thing again.

import { existsSync, mkdtempSync, mkdirSync, readdirSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { dirname, join, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

// Permissive licences that an Apache-2.0 project may include: all are on the Apache Software
// Foundation's "Category A" list (https://www.apache.org/legal/resolved.html) of licences whose
// terms an Apache-2.0 work meets without relicensing and without copyleft. deny.toml allows the
// same family for crates.
export const ALLOWED = new Set([
  'Apache-2.0',
  'MIT',
  'ISC',
  'BSD-2-Clause',
  'BSD-3-Clause',
  'Zlib',
]);

// Test tools under a weak, file-level copyleft licence, accepted by name: each must be a
// development dependency only (the lockfile marks it `dev`; nothing under web-client/ that the
// server serves imports it), must carry exactly the licence listed, and is used unmodified. The
// Apache Software Foundation lists MPL-2.0 in "Category B" (https://www.apache.org/legal/
// resolved.html#category-b): fine for an Apache-2.0 project to use unmodified, which is all a
// test run does. deny.toml grants per-crate exceptions the same way.
export const TEST_TOOL_EXCEPTIONS = [
  {
    name: 'axe-core',
    license: 'MPL-2.0',
    why: 'the accessibility rules engine the browser tests run on every screen (WCAG 2.1 A/AA); injected into the test browser only',
  },
];

/** Splits an SPDX licence expression into tokens: ids, parentheses, AND, OR, WITH. */
function tokenize(expression) {
  return expression.replace(/\(/g, ' ( ').replace(/\)/g, ' ) ').trim().split(/\s+/).filter(Boolean);
}

/**
 * Whether an SPDX expression is satisfied by `allowed`: `A OR B` needs one side, `A AND B`
 * both, and `A WITH exception` is accepted only when that exact pairing is in the list (an
 * exception can add terms). AND binds tighter than OR, and identifiers match without regard to
 * case (SPDX specification 2.3, annex D). Throws on an expression that does not parse, so a
 * malformed field cannot pass.
 */
export function satisfies(expression, allowed = ALLOWED) {
  const tokens = tokenize(expression);
  const permitted = new Set([...allowed].map((id) => id.toLowerCase()));
  let i = 0;
  const peek = () => tokens[i];
  const next = () => tokens[i++];
  const operator = (t) => t !== undefined && ['AND', 'OR', 'WITH'].includes(t.toUpperCase());
  function primary() {
    const t = next();
    if (t === undefined) throw new Error(`licence expression ends early: "${expression}"`);
    if (t === '(') {
      const value = orExpr();
      if (next() !== ')') throw new Error(`unbalanced parentheses in "${expression}"`);
      return value;
    }
    if (t === ')' || operator(t)) throw new Error(`unexpected "${t}" in "${expression}"`);
    if (peek() !== undefined && peek().toUpperCase() === 'WITH') {
      next();
      const exception = next();
      if (exception === undefined || exception === '(' || exception === ')' || operator(exception)) {
        throw new Error(`WITH needs an exception id in "${expression}"`);
      }
      return permitted.has(`${t} with ${exception}`.toLowerCase());
    }
    return permitted.has(t.toLowerCase());
  }
  function andExpr() {
    let value = primary();
    while (peek() !== undefined && peek().toUpperCase() === 'AND') {
      next();
      value = primary() && value;
    }
    return value;
  }
  function orExpr() {
    let value = andExpr();
    while (peek() !== undefined && peek().toUpperCase() === 'OR') {
      next();
      value = andExpr() || value;
    }
    return value;
  }
  const value = orExpr();
  if (i !== tokens.length) throw new Error(`trailing "${tokens[i]}" in "${expression}"`);
  return value;
}

/**
 * The licence a package.json or lockfile entry declares, as an SPDX expression, or null.
 * Old packages use `{ "type": "MIT" }` or a `licenses` array (each must hold: AND).
 */
export function declaredLicense(entry) {
  const l = entry.license;
  if (typeof l === 'string' && l.trim()) return l.trim();
  if (l && typeof l === 'object' && typeof l.type === 'string') return l.type;
  if (Array.isArray(entry.licenses) && entry.licenses.length > 0) {
    const ids = entry.licenses.map((x) => (typeof x === 'string' ? x : x && x.type)).filter(Boolean);
    if (ids.length === entry.licenses.length) return ids.map((id) => `(${id})`).join(' AND ');
  }
  return null;
}

/** Package folders under a node_modules folder, scoped (`@scope/name`) and nested included. */
function installedPackages(root, prefix = 'node_modules') {
  const folder = join(root, prefix);
  if (!existsSync(folder)) return [];
  const found = [];
  for (const entry of readdirSync(folder, { withFileTypes: true })) {
    if (!entry.isDirectory() || entry.name.startsWith('.')) continue;
    const names = entry.name.startsWith('@')
      ? readdirSync(join(folder, entry.name), { withFileTypes: true })
        .filter((e) => e.isDirectory())
        .map((e) => `${entry.name}/${e.name}`)
      : [entry.name];
    for (const name of names) {
      const path = `${prefix}/${name}`;
      if (existsSync(join(root, path, 'package.json'))) found.push(path);
      found.push(...installedPackages(root, `${path}/node_modules`));
    }
  }
  return found;
}

/** The package name a lockfile key (`node_modules/a/node_modules/@s/b`) stands for. */
function nameOfPath(path) {
  return path.slice(path.lastIndexOf('node_modules/') + 'node_modules/'.length);
}

/**
 * Checks the npm project in `dir`. Returns { packages: [{name, version, license}], problems:
 * [string] }; a project without problems passes.
 */
export function check(dir) {
  const lockPath = join(dir, 'package-lock.json');
  const lock = JSON.parse(readFileSync(lockPath, 'utf8'));
  if (!lock.packages || typeof lock.packages !== 'object') {
    throw new Error(`${lockPath}: no "packages" map (lockfileVersion 2 or later is needed)`);
  }
  const problems = [];
  const packages = [];
  const installed = existsSync(join(dir, 'node_modules'));
  for (const [path, entry] of Object.entries(lock.packages)) {
    if (path === '') continue; // The project itself; its licence is the repository's.
    if (entry.link) continue; // A workspace link; its target has its own entry.
    const name = entry.name || nameOfPath(path);
    const license = declaredLicense(entry);
    packages.push({ name, version: entry.version, license });
    if (license === null) {
      problems.push(`${name}@${entry.version}: the lockfile records no licence`);
    } else {
      try {
        const exception = TEST_TOOL_EXCEPTIONS.find((x) => x.name === name && x.license === license);
        if (exception && entry.dev !== true) {
          problems.push(`${name}@${entry.version}: "${license}" is accepted for a test tool only, and the lockfile does not mark it dev`);
        } else if (!exception && !satisfies(license)) {
          problems.push(`${name}@${entry.version}: "${license}" is not in the allow-list`);
        }
      } catch (e) {
        problems.push(`${name}@${entry.version}: ${e.message}`);
      }
    }
    const manifest = join(dir, path, 'package.json');
    if (installed && existsSync(manifest)) {
      const own = declaredLicense(JSON.parse(readFileSync(manifest, 'utf8')));
      if (own !== license) {
        problems.push(`${name}@${entry.version}: installed package.json says "${own}", the lockfile "${license}"`);
      }
    } else if (installed && !entry.optional) {
      problems.push(`${name}@${entry.version}: in the lockfile but not installed (run npm ci)`);
    }
  }
  for (const path of installedPackages(dir)) {
    if (!(path in lock.packages)) problems.push(`${path}: installed but not in package-lock.json`);
  }
  return { packages, problems };
}

function summarize(dir, { packages, problems }) {
  const byLicense = new Map();
  for (const p of packages) {
    const key = p.license ?? '(none)';
    byLicense.set(key, [...(byLicense.get(key) ?? []), `${p.name}@${p.version}`]);
  }
  console.log(`npm licences in ${dir}: ${packages.length} package(s)`);
  for (const [license, names] of [...byLicense].sort()) {
    console.log(`  ${license}: ${names.length} (${names.join(', ')})`);
  }
  for (const p of problems) console.error(`  FAIL ${p}`);
  console.log(problems.length === 0 ? 'npm licences: ok' : `npm licences: ${problems.length} problem(s)`);
}

/** Writes a fixture project: `packages` maps lockfile path to { license, installedLicense,
 * dev }. */
function writeFixture(root, packages) {
  const lock = { name: 'fixture', version: '0.0.0', lockfileVersion: 3, requires: true, packages: { '': { name: 'fixture' } } };
  for (const [path, p] of Object.entries(packages)) {
    lock.packages[path] = { version: '1.0.0', license: p.license, ...(p.dev ? { dev: true } : {}) };
    mkdirSync(join(root, path), { recursive: true });
    writeFileSync(join(root, path, 'package.json'),
      JSON.stringify({ name: nameOfPath(path), version: '1.0.0', license: p.installedLicense ?? p.license }));
  }
  writeFileSync(join(root, 'package-lock.json'), JSON.stringify(lock));
}

/** Runs the check on planted fixtures; throws unless each bad case fails and the good one passes. */
function selfTest() {
  const cases = [
    { what: 'permissive packages only', fails: false, packages: {
      'node_modules/ok-mit': { license: 'MIT' },
      'node_modules/@scope/ok-dual': { license: '(MIT OR GPL-3.0-only)' },
      'node_modules/ok-mit/node_modules/ok-nested': { license: 'ISC' },
    } },
    { what: 'a planted GPL-3.0-only package', fails: true, packages: {
      'node_modules/ok-mit': { license: 'MIT' },
      'node_modules/planted-gpl': { license: 'GPL-3.0-only' },
    } },
    { what: 'a conjunction with a copyleft licence', fails: true, packages: {
      'node_modules/planted-and': { license: 'MIT AND LGPL-2.1-or-later' },
    } },
    { what: 'a listed test tool as a dev dependency', fails: false, packages: {
      'node_modules/axe-core': { license: 'MPL-2.0', dev: true },
    } },
    { what: 'a listed test tool shipped as a runtime dependency', fails: true, packages: {
      'node_modules/axe-core': { license: 'MPL-2.0' },
    } },
    { what: 'an unlisted MPL-2.0 dev dependency', fails: true, packages: {
      'node_modules/planted-mpl': { license: 'MPL-2.0', dev: true },
    } },
    { what: 'a package without a licence', fails: true, packages: {
      'node_modules/planted-none': { license: undefined },
    } },
    { what: 'an installed package.json that disagrees with the lockfile', fails: true, packages: {
      'node_modules/planted-swap': { license: 'MIT', installedLicense: 'AGPL-3.0-only' },
    } },
  ];
  for (const c of cases) {
    const root = mkdtempSync(join(tmpdir(), 'check-licenses-'));
    try {
      writeFixture(root, c.packages);
      const result = check(root);
      const failed = result.problems.length > 0;
      if (failed !== c.fails) {
        throw new Error(`self-test "${c.what}": expected ${c.fails ? 'a failure' : 'a pass'}, got ${JSON.stringify(result.problems)}`);
      }
      if (c.fails && !result.problems.some((p) => p.includes('planted-') || p.includes('axe-core'))) {
        throw new Error(`self-test "${c.what}": the failure does not name the planted package: ${result.problems}`);
      }
      console.log(`self-test: ${c.what}: ${failed ? 'rejected' : 'accepted'} as expected`);
    } finally {
      rmSync(root, { recursive: true, force: true });
    }
  }
  // An unlisted package in node_modules is caught even when the lockfile is clean.
  const root = mkdtempSync(join(tmpdir(), 'check-licenses-'));
  try {
    writeFixture(root, { 'node_modules/ok-mit': { license: 'MIT' } });
    mkdirSync(join(root, 'node_modules/planted-extra'), { recursive: true });
    writeFileSync(join(root, 'node_modules/planted-extra/package.json'), JSON.stringify({ name: 'planted-extra', license: 'MIT' }));
    if (!check(root).problems.some((p) => p.includes('planted-extra'))) {
      throw new Error('self-test "a package missing from the lockfile": not caught');
    }
    console.log('self-test: a package missing from the lockfile: rejected as expected');
  } finally {
    rmSync(root, { recursive: true, force: true });
  }
}

if (process.argv[1] && resolve(process.argv[1]) === fileURLToPath(import.meta.url)) {
  const args = process.argv.slice(2);
  if (args[0] === '--self-test') {
    selfTest();
  } else {
    const dir = resolve(args[0] ?? join(dirname(fileURLToPath(import.meta.url)), '..'));
    const result = check(dir);
    summarize(dir, result);
    if (result.problems.length > 0) process.exit(1);
  }
}
