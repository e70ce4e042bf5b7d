//! Test helpers: the shared benchmark directory and an exact value
//! iteration for two-state POMDPs, independent of the solver under test.

#![allow(dead_code)]

use beliefbus_pomdp::Pomdp;
use std::path::PathBuf;

/// `$BELIEFBUS_POMDP_DATA`, else `<repo>/../shared/data/pomdp` (where CI
/// and the team's machines keep the third-party problems). Panics naming
/// the path when the file is missing: a skipped benchmark is a silent pass.
pub fn shared_problem(name: &str) -> PathBuf {
    let dir = std::env::var_os("BELIEFBUS_POMDP_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/pomdp")
        });
    let path = dir.join(name);
    assert!(
        path.is_file(),
        "benchmark problem {} not found (set BELIEFBUS_POMDP_DATA to the directory holding it)",
        path.display()
    );
    path
}

pub fn load_shared(name: &str) -> Pomdp {
    beliefbus_pomdp::parse_file(&shared_problem(name)).unwrap_or_else(|e| panic!("{e}"))
}

pub fn load_own(name: &str) -> Pomdp {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name);
    beliefbus_pomdp::parse_file(&path).unwrap_or_else(|e| panic!("{e}"))
}

/// An α-vector of a two-state problem: value `(1−p) v0 + p v1` at
/// `p = b(state 1)`, with its first action.
#[derive(Clone, Copy, Debug)]
pub struct Line {
    pub v0: f64,
    pub v1: f64,
    pub action: usize,
}

impl Line {
    pub fn at(&self, p: f64) -> f64 {
        (1.0 - p) * self.v0 + p * self.v1
    }
}

/// The upper envelope of `lines` over p ∈ [0, 1] (exact pruning in one
/// dimension): sort by slope, keep the upper hull with a stack, then drop
/// the lines whose hull interval misses [0, 1].
pub fn envelope(lines: &[Line]) -> Vec<Line> {
    let slope = |l: &Line| l.v1 - l.v0;
    let mut sorted = lines.to_vec();
    sorted.sort_by(|a, b| slope(a).total_cmp(&slope(b)).then(a.v0.total_cmp(&b.v0)));
    // p where a and b (slope(a) < slope(b)) cross
    let cross = |a: &Line, b: &Line| (a.v0 - b.v0) / (slope(b) - slope(a));
    let mut hull: Vec<Line> = Vec::new();
    for l in sorted {
        if let Some(last) = hull.last() {
            if (slope(last) - slope(&l)).abs() <= 1e-9 {
                // parallel (up to rounding): keep the higher one
                if last.v0 >= l.v0 {
                    continue;
                }
                hull.pop();
            }
        }
        while hull.len() >= 2 {
            let (a, b) = (&hull[hull.len() - 2], &hull[hull.len() - 1]);
            if cross(a, &l) <= cross(a, b) + 1e-12 {
                hull.pop();
            } else {
                break;
            }
        }
        hull.push(l);
    }
    let n = hull.len();
    (0..n)
        .filter(|&i| {
            let from = if i == 0 {
                f64::NEG_INFINITY
            } else {
                cross(&hull[i - 1], &hull[i])
            };
            let to = if i + 1 == n {
                f64::INFINITY
            } else {
                cross(&hull[i], &hull[i + 1])
            };
            to > 0.0 && from < 1.0 && to > from
        })
        .map(|i| hull[i])
        .collect()
}

/// One exact dynamic-programming step `V ← H V` with pruning.
fn backup(p: &Pomdp, v: &[Line]) -> Vec<Line> {
    let g = p.discount;
    let mut all = Vec::new();
    for a in 0..p.n_actions() {
        let mut acc = vec![Line {
            v0: p.reward[a][0],
            v1: p.reward[a][1],
            action: a,
        }];
        for o in 0..p.n_obs() {
            // g(s) = γ Σ_{s'} T(s'|s,a) O(o|s',a) α(s')
            let proj: Vec<Line> = v
                .iter()
                .map(|al| {
                    let f = |s: usize| {
                        g * (0..2)
                            .map(|s2| {
                                p.trans[a].get(s, s2)
                                    * p.obs[a].get(s2, o)
                                    * if s2 == 0 { al.v0 } else { al.v1 }
                            })
                            .sum::<f64>()
                    };
                    Line {
                        v0: f(0),
                        v1: f(1),
                        action: a,
                    }
                })
                .collect();
            let sums: Vec<Line> = acc
                .iter()
                .flat_map(|x| {
                    proj.iter().map(move |y| Line {
                        v0: x.v0 + y.v0,
                        v1: x.v1 + y.v1,
                        action: a,
                    })
                })
                .collect();
            acc = envelope(&sums);
        }
        all.extend(acc);
    }
    envelope(&all)
}

/// `[lower, upper]` on V*(b₀) by exact value iteration from the constant
/// bounds `min R/(1−γ)` and `max R/(1−γ)` (both iterations are monotone),
/// stopped when they are within `tol`; also the final lower α-set.
pub fn exact_two_state(p: &Pomdp, tol: f64) -> (f64, f64, Vec<Line>) {
    assert_eq!(p.n_states(), 2);
    let (lo, hi) = p.reward_range();
    let c = |v: f64| {
        vec![Line {
            v0: v / (1.0 - p.discount),
            v1: v / (1.0 - p.discount),
            action: 0,
        }]
    };
    let (mut l, mut u) = (c(lo), c(hi));
    let b = p.start[1];
    let val = |v: &[Line]| v.iter().map(|x| x.at(b)).fold(f64::NEG_INFINITY, f64::max);
    for _ in 0..100_000 {
        if val(&u) - val(&l) < tol {
            break;
        }
        l = backup(p, &l);
        u = backup(p, &u);
    }
    (val(&l), val(&u), l)
}
