//! A directed graph of named nodes whose edges carry evidence (where in the sources each edge
//! comes from), its strongly connected components, and a readable account of each cycle.
//!
//! The module graph uses it twice: once with one node per source file, and once per folder with
//! one node per entry of that folder (a file or a subfolder).

use std::collections::{BTreeMap, BTreeSet, VecDeque};

/// One strongly connected component of more than one node.
#[derive(Debug)]
pub struct Cycle {
    /// `"<prefix>: <node>, <node>, ..."`, members sorted: names the component exactly.
    pub key: String,
    /// A readable account: the key, one shortest cycle, then every edge inside the component
    /// with its evidence (one line per piece of evidence).
    pub report: String,
}

/// Pieces of evidence printed per edge of a component; the rest are counted. Simulator choice:
/// a folder edge can stand for dozens of file edges, and the first few show where it comes from
/// while the count says how much work breaking it takes.
const EVIDENCE_SHOWN: usize = 4;

#[derive(Default)]
pub struct Digraph {
    names: Vec<String>,
    /// Evidence of each edge, in the order it was added.
    edges: BTreeMap<(usize, usize), Vec<String>>,
}

impl Digraph {
    /// A graph of the named nodes and no edges.
    pub fn new(names: Vec<String>) -> Self {
        Digraph {
            names,
            edges: BTreeMap::new(),
        }
    }

    /// Adds the edge `from -> to` (self-edges are ignored), with one piece of evidence.
    pub fn add(&mut self, from: usize, to: usize, evidence: String) {
        if from != to {
            self.edges.entry((from, to)).or_default().push(evidence);
        }
    }

    pub fn name(&self, node: usize) -> &str {
        &self.names[node]
    }

    /// Every edge as `"from -> to"`.
    pub fn edge_names(&self) -> BTreeSet<String> {
        self.edges
            .keys()
            .map(|&(a, b)| format!("{} -> {}", self.names[a], self.names[b]))
            .collect()
    }

    fn successors(&self, node: usize) -> impl Iterator<Item = usize> + '_ {
        self.edges
            .range((node, 0)..(node + 1, 0))
            .map(|(&(_, to), _)| to)
    }

    /// Components of more than one node for which `keep` holds, described with keys
    /// `"<prefix>: ..."`, sorted by key.
    pub fn cycles(&self, prefix: &str, keep: impl Fn(&[usize]) -> bool) -> Vec<Cycle> {
        let mut cycles: Vec<Cycle> = self
            .components()
            .into_iter()
            .filter(|c| c.len() > 1 && keep(c))
            .map(|members| self.describe(prefix, &members))
            .collect();
        cycles.sort_by(|a, b| a.key.cmp(&b.key));
        cycles
    }

    /// Tarjan's strongly connected components.
    fn components(&self) -> Vec<Vec<usize>> {
        struct State {
            index: Vec<Option<usize>>,
            low: Vec<usize>,
            on_stack: Vec<bool>,
            stack: Vec<usize>,
            next: usize,
            out: Vec<Vec<usize>>,
        }
        fn visit(g: &Digraph, s: &mut State, v: usize) {
            s.index[v] = Some(s.next);
            s.low[v] = s.next;
            s.next += 1;
            s.stack.push(v);
            s.on_stack[v] = true;
            for w in g.successors(v) {
                match s.index[w] {
                    None => {
                        visit(g, s, w);
                        s.low[v] = s.low[v].min(s.low[w]);
                    }
                    Some(iw) if s.on_stack[w] => s.low[v] = s.low[v].min(iw),
                    Some(_) => {}
                }
            }
            if Some(s.low[v]) == s.index[v] {
                let mut component = Vec::new();
                while let Some(w) = s.stack.pop() {
                    s.on_stack[w] = false;
                    component.push(w);
                    if w == v {
                        break;
                    }
                }
                s.out.push(component);
            }
        }
        let n = self.names.len();
        let mut s = State {
            index: vec![None; n],
            low: vec![0; n],
            on_stack: vec![false; n],
            stack: Vec::new(),
            next: 0,
            out: Vec::new(),
        };
        for v in 0..n {
            if s.index[v].is_none() {
                visit(self, &mut s, v);
            }
        }
        s.out
    }

    fn describe(&self, prefix: &str, members: &[usize]) -> Cycle {
        let inside: BTreeSet<usize> = members.iter().copied().collect();
        let mut names: Vec<(&str, usize)> = members.iter().map(|&m| (self.name(m), m)).collect();
        names.sort();
        let key = format!(
            "{prefix}: {}",
            names.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", ")
        );
        // The shortest cycle through the first member, by breadth-first search inside the
        // component.
        let start = names[0].1;
        let mut previous: BTreeMap<usize, usize> = BTreeMap::new();
        let mut queue = VecDeque::from([start]);
        'search: while let Some(v) = queue.pop_front() {
            for w in self.successors(v).filter(|w| inside.contains(w)) {
                if w == start {
                    previous.insert(start, v);
                    break 'search;
                }
                if let std::collections::btree_map::Entry::Vacant(e) = previous.entry(w) {
                    e.insert(v);
                    queue.push_back(w);
                }
            }
        }
        let mut cycle = vec![start];
        let mut at = previous[&start];
        while at != start {
            cycle.push(at);
            at = previous[&at];
        }
        cycle.push(start);
        cycle.reverse();
        let mut report = format!(
            "{key}\n    cycle: {}\n",
            cycle
                .iter()
                .map(|&m| self.name(m))
                .collect::<Vec<_>>()
                .join(" -> ")
        );
        let mut blocks: Vec<(String, &Vec<String>)> = self
            .edges
            .iter()
            .filter(|((from, to), _)| inside.contains(from) && inside.contains(to))
            .map(|(&(from, to), evidence)| {
                (
                    format!("{} -> {}", self.name(from), self.name(to)),
                    evidence,
                )
            })
            .collect();
        blocks.sort();
        for (edge, evidence) in blocks {
            for e in evidence.iter().take(EVIDENCE_SHOWN) {
                report.push_str(&format!("    {edge}   {e}\n"));
            }
            if evidence.len() > EVIDENCE_SHOWN {
                let more = evidence.len() - EVIDENCE_SHOWN;
                report.push_str(&format!("    {edge}   (and {more} more)\n"));
            }
        }
        Cycle { key, report }
    }
}
