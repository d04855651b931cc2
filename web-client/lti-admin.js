// Admin page: register, list and remove LTI 1.3 platforms; rotate the tool's key.

import { api, setCsrf } from './api.js';

const $ = (id) => document.getElementById(id);

function say(text) {
  $('message').textContent = text || '';
}

function el(tag, props = {}, ...children) {
  const e = document.createElement(tag);
  Object.assign(e, props);
  for (const c of children) e.append(c);
  return e;
}

async function refresh() {
  const platforms = await api('GET', '/api/admin/lti/platforms');
  $('platforms').tBodies[0].replaceChildren(...platforms.map((p) => {
    const remove = el('button', { type: 'button', textContent: 'Remove' });
    remove.setAttribute('aria-label', `Remove ${p.name}`);
    remove.addEventListener('click', async () => {
      try { await api('DELETE', `/api/admin/lti/platforms/${p.id}`); await refresh(); } catch (e) { say(e.message); }
    });
    return el('tr', {}, el('td', { textContent: p.name }), el('td', { textContent: p.issuer }),
      el('td', { textContent: p.client_id }), el('td', { textContent: p.deployment_ids.join(', ') }), el('td', {}, remove));
  }));
}

$('platform-form').addEventListener('submit', async (ev) => {
  ev.preventDefault();
  const f = new FormData(ev.target);
  const body = Object.fromEntries(['name', 'issuer', 'client_id', 'auth_url', 'token_url', 'jwks_url'].map((k) => [k, f.get(k).trim()]));
  body.deployment_ids = f.get('deployment_ids').split(',').map((d) => d.trim()).filter(Boolean);
  for (const k of ['lineitems_url', 'memberships_url']) if (f.get(k).trim()) body[k] = f.get(k).trim();
  try {
    await api('POST', '/api/admin/lti/platforms', body);
    ev.target.reset();
    say('Registered.');
    await refresh();
  } catch (e) {
    say(e.message);
  }
});

$('rotate').addEventListener('click', async () => {
  try {
    const r = await api('POST', '/api/admin/lti/keys/rotate');
    say(`New signing key ${r.kid}; ${r.published.length} keys published.`);
  } catch (e) {
    say(e.message);
  }
});

async function start() {
  const origin = location.origin;
  $('tool-urls').replaceChildren(...[['Login initiation', '/lti/login'], ['Launch / redirect', '/lti/launch'],
    ['Deep linking', '/lti/launch'], ['Public keys (JWKS)', '/lti/jwks']]
    .flatMap(([k, p]) => [el('dt', { textContent: k }), el('dd', { textContent: origin + p })]));
  try {
    const me = await api('GET', '/api/auth/me');
    setCsrf(me.csrf_token);
    if (me.user.role !== 'admin') { say('This page is for admins.'); return; }
    await refresh();
  } catch (e) {
    say(`Log in as an admin first (${e.message}).`);
  }
}

start();
