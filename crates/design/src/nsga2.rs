//! NSGA-II (Deb, Pratap, Agarwal & Meyarivan, IEEE TEC 6(2), 2002) with Deb's
//! constrained domination, as an ask/tell loop: [`Search::ask`] gives the points of the
//! next generation, the caller evaluates them however it likes (in a loop, on rayon,
//! on a Dask cluster through the Python package) and hands the results back with
//! [`Search::tell`]. The state is plain data (serde), so a search resumes from its file.
//!
//! Why not a crate: the Rust NSGA-II crates we looked at (`optirustic`, `moors`) own
//! the evaluation loop (a problem trait called per individual), so a generation cannot
//! leave the process as one batch for an external engine, and their state cannot be
//! saved and resumed; the algorithm itself is the 150 lines below.
//!
//! Operators: binary tournament on (rank, crowding distance); simulated binary
//! crossover (η_c = 15, probability 0.9) and polynomial mutation (η_m = 20,
//! probability 1/n), both bounded (Deb & Agrawal 1995; Deb & Goyal 1996). Every random
//! number comes from the seeded generator of [`cellinject_numeric::rng::Rng`], one
//! stream per generation, so a seed gives one front whatever evaluates the points and
//! however often the search is resumed.

use std::cmp::Ordering;

use cellinject_numeric::rng::Rng;
use serde::{Deserialize, Serialize};

/// Distribution index of the crossover.
const ETA_C: f64 = 15.0;
/// Distribution index of the mutation.
const ETA_M: f64 = 20.0;
/// Crossover probability.
const P_CROSS: f64 = 0.9;

/// One evaluated point.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Member {
    /// The variables.
    pub x: Vec<f64>,
    /// Objectives, all minimised.
    pub f: Vec<f64>,
    /// Constraint violation, 0 when feasible.
    pub cv: f64,
    /// What the caller keeps with the point (a study keeps its record).
    #[serde(default)]
    pub data: serde_json::Value,
}

/// The search's state between generations.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Search {
    /// Bounds of each variable.
    pub bounds: Vec<[f64; 2]>,
    /// Population size (even).
    pub population: usize,
    /// Seed.
    pub seed: u64,
    /// Generations told so far (0: the initial population is next).
    pub generation: usize,
    /// The current parents, sorted by (rank, crowding).
    pub members: Vec<Member>,
    /// The number of evaluations told.
    pub evaluations: usize,
}

/// Deb's constrained domination: `a` dominates `b`.
fn dominates(a: &Member, b: &Member) -> bool {
    if a.cv > 0.0 || b.cv > 0.0 {
        return a.cv < b.cv;
    }
    let mut better = false;
    for (x, y) in a.f.iter().zip(&b.f) {
        if x > y {
            return false;
        }
        if x < y {
            better = true;
        }
    }
    better
}

/// Fronts of non-dominated sorting (Deb 2002, fast-non-dominated-sort), as indices.
pub fn fronts(m: &[Member]) -> Vec<Vec<usize>> {
    let n = m.len();
    let mut dominated_by = vec![0usize; n];
    let mut dominates_list: Vec<Vec<usize>> = vec![Vec::new(); n];
    for i in 0..n {
        for j in 0..n {
            if i != j && dominates(&m[i], &m[j]) {
                dominates_list[i].push(j);
            } else if i != j && dominates(&m[j], &m[i]) {
                dominated_by[i] += 1;
            }
        }
    }
    let mut out = Vec::new();
    let mut current: Vec<usize> = (0..n).filter(|&i| dominated_by[i] == 0).collect();
    while !current.is_empty() {
        let mut next = Vec::new();
        for &i in &current {
            for &j in &dominates_list[i] {
                dominated_by[j] -= 1;
                if dominated_by[j] == 0 {
                    next.push(j);
                }
            }
        }
        next.sort_unstable();
        out.push(current);
        current = next;
    }
    out
}

/// Crowding distance of each member of one front.
fn crowding(m: &[Member], front: &[usize]) -> Vec<f64> {
    let n = front.len();
    let mut d = vec![0.0; n];
    if n <= 2 {
        return vec![f64::INFINITY; n];
    }
    let objectives = m[front[0]].f.len();
    for k in 0..objectives {
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| {
            m[front[a]].f[k]
                .total_cmp(&m[front[b]].f[k])
                .then(a.cmp(&b))
        });
        let lo = m[front[order[0]]].f[k];
        let hi = m[front[order[n - 1]]].f[k];
        d[order[0]] = f64::INFINITY;
        d[order[n - 1]] = f64::INFINITY;
        let span = hi - lo;
        if span > 0.0 && span.is_finite() {
            for w in 1..n - 1 {
                let gap = m[front[order[w + 1]]].f[k] - m[front[order[w - 1]]].f[k];
                d[order[w]] += gap / span;
            }
        }
    }
    d
}

/// The best `n` of `pool` by (rank, crowding), in that order; ties by position.
fn select(pool: Vec<Member>, n: usize) -> Vec<Member> {
    let mut ranked: Vec<(usize, f64, usize)> = Vec::with_capacity(pool.len());
    for (rank, front) in fronts(&pool).iter().enumerate() {
        let d = crowding(&pool, front);
        for (k, &i) in front.iter().enumerate() {
            ranked.push((rank, d[k], i));
        }
    }
    ranked.sort_by(|a, b| a.0.cmp(&b.0).then(b.1.total_cmp(&a.1)).then(a.2.cmp(&b.2)));
    ranked
        .iter()
        .take(n)
        .map(|&(_, _, i)| pool[i].clone())
        .collect()
}

impl Search {
    /// A new search over `bounds` with `population` members (rounded up to even, at
    /// least 4). `start`, when given and inside the bounds, is one member of the first
    /// generation (the description's own design, so the front can only improve on it).
    pub fn new(bounds: Vec<[f64; 2]>, population: usize, seed: u64) -> Search {
        let population = population.max(4).div_ceil(2) * 2;
        Search {
            bounds,
            population,
            seed,
            generation: 0,
            members: Vec::new(),
            evaluations: 0,
        }
    }

    fn rng(&self) -> Rng {
        Rng::new(self.seed, self.generation as u64)
    }

    /// The points to evaluate next: the initial population (with `start` first when
    /// given), then each generation's offspring.
    pub fn ask(&self, start: Option<&[f64]>) -> Vec<Vec<f64>> {
        let mut rng = self.rng();
        let n = self.bounds.len();
        if self.generation == 0 {
            let mut out: Vec<Vec<f64>> = Vec::with_capacity(self.population);
            if let Some(s) = start
                && s.len() == n
                && s.iter()
                    .zip(&self.bounds)
                    .all(|(x, b)| *x >= b[0] && *x <= b[1])
            {
                out.push(s.to_vec());
            }
            while out.len() < self.population {
                out.push(self.bounds.iter().map(|b| rng.range(b[0], b[1])).collect());
            }
            return out;
        }
        let parents = &self.members;
        let pick = |rng: &mut Rng| -> usize {
            let a = (rng.next_u64() % parents.len() as u64) as usize;
            let b = (rng.next_u64() % parents.len() as u64) as usize;
            // Parents are sorted by (rank, crowding): the lower index wins.
            a.min(b)
        };
        let mut out = Vec::with_capacity(self.population);
        while out.len() < self.population {
            let p1 = &parents[pick(&mut rng)].x;
            let p2 = &parents[pick(&mut rng)].x;
            let (mut c1, mut c2) = (p1.clone(), p2.clone());
            if rng.uniform() < P_CROSS {
                for i in 0..n {
                    let u = rng.uniform();
                    if u <= 0.5 {
                        let [lo, hi] = self.bounds[i];
                        let (a, b) = sbx(p1[i], p2[i], lo, hi, &mut rng);
                        c1[i] = a;
                        c2[i] = b;
                    }
                }
            }
            for c in [&mut c1, &mut c2] {
                for i in 0..n {
                    if rng.uniform() < 1.0 / n as f64 {
                        let [lo, hi] = self.bounds[i];
                        c[i] = mutate(c[i], lo, hi, &mut rng);
                    }
                }
            }
            out.push(c1);
            if out.len() < self.population {
                out.push(c2);
            }
        }
        out
    }

    /// Hands back the evaluated points of the last [`Search::ask`], in its order.
    pub fn tell(&mut self, evaluated: Vec<Member>) {
        self.evaluations += evaluated.len();
        let mut pool = std::mem::take(&mut self.members);
        pool.extend(evaluated);
        self.members = select(pool, self.population);
        self.generation += 1;
    }

    /// The current non-dominated feasible members (rank 0 with no violation), without
    /// repeats, in population order.
    pub fn front(&self) -> Vec<Member> {
        let f = fronts(&self.members);
        let mut out: Vec<Member> = Vec::new();
        if let Some(first) = f.first() {
            let mut idx = first.clone();
            idx.sort_unstable();
            for i in idx {
                let m = &self.members[i];
                if m.cv == 0.0 && !out.iter().any(|o| o.x == m.x) {
                    out.push(m.clone());
                }
            }
        }
        out
    }
}

/// Bounded simulated binary crossover of one variable (Deb & Agrawal 1995, as in
/// Deb's NSGA-II code).
fn sbx(x1: f64, x2: f64, lo: f64, hi: f64, rng: &mut Rng) -> (f64, f64) {
    if (x1 - x2).abs() <= 1e-14 * (hi - lo) {
        return (x1, x2);
    }
    let (y1, y2) = if x1 < x2 { (x1, x2) } else { (x2, x1) };
    let u = rng.uniform();
    let child = |beta: f64| {
        let alpha = 2.0 - beta.powf(-(ETA_C + 1.0));
        if u <= 1.0 / alpha {
            (u * alpha).powf(1.0 / (ETA_C + 1.0))
        } else {
            (1.0 / (2.0 - u * alpha)).powf(1.0 / (ETA_C + 1.0))
        }
    };
    let beta_lo = 1.0 + 2.0 * (y1 - lo) / (y2 - y1);
    let betaq = child(beta_lo);
    let c1 = 0.5 * ((y1 + y2) - betaq * (y2 - y1));
    let beta_hi = 1.0 + 2.0 * (hi - y2) / (y2 - y1);
    let betaq = child(beta_hi);
    let c2 = 0.5 * ((y1 + y2) + betaq * (y2 - y1));
    let (c1, c2) = (c1.clamp(lo, hi), c2.clamp(lo, hi));
    if rng.uniform() <= 0.5 {
        (c2, c1)
    } else {
        (c1, c2)
    }
}

/// Bounded polynomial mutation (Deb & Goyal 1996).
fn mutate(x: f64, lo: f64, hi: f64, rng: &mut Rng) -> f64 {
    let span = hi - lo;
    let d1 = (x - lo) / span;
    let d2 = (hi - x) / span;
    let u = rng.uniform();
    let p = 1.0 / (ETA_M + 1.0);
    let dq = if u < 0.5 {
        let v = 2.0 * u + (1.0 - 2.0 * u) * (1.0 - d1).powf(ETA_M + 1.0);
        v.powf(p) - 1.0
    } else {
        let v = 2.0 * (1.0 - u) + 2.0 * (u - 0.5) * (1.0 - d2).powf(ETA_M + 1.0);
        1.0 - v.powf(p)
    };
    (x + dq * span).clamp(lo, hi)
}

/// Orders members for output: by their first objective, then the rest.
pub fn order(a: &Member, b: &Member) -> Ordering {
    a.f.iter()
        .zip(&b.f)
        .map(|(x, y)| x.total_cmp(y))
        .find(|o| *o != Ordering::Equal)
        .unwrap_or(Ordering::Equal)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(seed: u64, f: impl Fn(&[f64]) -> (Vec<f64>, f64)) -> Search {
        let mut s = Search::new(vec![[0.0, 1.0], [0.0, 1.0]], 40, seed);
        for _ in 0..60 {
            let pts = s.ask(None);
            let evaluated = pts
                .into_iter()
                .map(|x| {
                    let (f, cv) = f(&x);
                    Member {
                        x,
                        f,
                        cv,
                        data: serde_json::Value::Null,
                    }
                })
                .collect();
            s.tell(evaluated);
        }
        s
    }

    /// Schaffer-like two-objective problem with a known front: f1 = x0, f2 = 1 − x0
    /// at x1 = 0; the front must lie at x1 ≈ 0 and be non-dominated.
    #[test]
    fn finds_a_known_front_and_it_is_non_dominated() {
        let s = run(7, |x| (vec![x[0], 1.0 - x[0] + 4.0 * x[1] * x[1]], 0.0));
        let front = s.front();
        assert!(front.len() >= 20, "{}", front.len());
        // Distance above the true front f2 = 1 − f1: 4·x1².
        let mut excess: Vec<f64> = front.iter().map(|m| m.f[1] - (1.0 - m.f[0])).collect();
        excess.sort_by(f64::total_cmp);
        // Half the members on the front to 1e-4 (a population of 40 leaves gaps of
        // about 1/40 along the front, in which a slightly worse member stays
        // non-dominated), and every part of the true front has a member near it.
        let median = excess[excess.len() / 2];
        assert!(median < 1e-4, "median {median}");
        for k in 0..=20 {
            let t = k as f64 / 20.0;
            let near = front
                .iter()
                .map(|m| ((m.f[0] - t).powi(2) + (m.f[1] - (1.0 - t)).powi(2)).sqrt())
                .fold(f64::INFINITY, f64::min);
            assert!(near < 0.05, "nothing near ({t}, {})", 1.0 - t);
        }
        // It spans the front.
        let lo = front.iter().map(|m| m.f[0]).fold(1.0, f64::min);
        let hi = front.iter().map(|m| m.f[0]).fold(0.0, f64::max);
        assert!(lo < 0.05 && hi > 0.95, "{lo}..{hi}");
        for a in &front {
            for b in &front {
                assert!(!dominates(a, b));
            }
        }
    }

    #[test]
    fn constraints_are_respected_and_the_seed_fixes_the_result() {
        // Minimise x0 subject to x0 + x1 >= 1.2 (cv: the shortfall).
        let f = |x: &[f64]| (vec![x[0]], (1.2 - x[0] - x[1]).max(0.0));
        let a = run(3, f);
        let b = run(3, f);
        assert_eq!(a, b);
        let best = &a.front()[0];
        assert_eq!(best.cv, 0.0);
        // The optimum is x0 = 0.2 at x1 = 1.
        assert!((best.x[0] - 0.2).abs() < 0.01, "{:?}", best.x);
        let c = run(4, f);
        assert_ne!(a.members, c.members);
    }

    #[test]
    fn resuming_from_saved_state_gives_the_same_search() {
        let f = |x: &[f64]| vec![x[0] + x[1], (x[0] - 1.0).powi(2)];
        let mut a = Search::new(vec![[0.0, 1.0], [0.0, 1.0]], 12, 9);
        let mut b = a.clone();
        for g in 0..10 {
            for s in [&mut a, &mut b] {
                let pts = s.ask(None);
                let e = pts
                    .into_iter()
                    .map(|x| Member {
                        f: f(&x),
                        x,
                        cv: 0.0,
                        data: serde_json::Value::Null,
                    })
                    .collect();
                s.tell(e);
            }
            if g == 4 {
                let json = serde_json::to_string(&b).unwrap();
                b = serde_json::from_str(&json).unwrap();
            }
        }
        assert_eq!(a, b);
    }
}
