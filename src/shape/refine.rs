//! Conforming local refinement of a tet mesh by longest-edge bisection (Rivara's LEPP), for
//! background grids that must resolve a thin feature without refining the whole box.
//!
//! # Why
//!
//! A marched body resolves what its background grid resolves (see [`super::marching`]). The
//! thickness fit's cavity at high t is a thin lens around the solid's medial sheet (the turtle
//! at t = 0.7: at most five 40-cell spacings across and thinner towards its rim), and what the
//! samples make of it changes more with the grid's alignment than with t. A uniformly finer
//! grid costs 8× the tets per halving of h everywhere; refining only the tets near the inner
//! wall costs a few per cent of that.
//!
//! # The bisection
//!
//! Every edge has a global rank: its length (lengths within a relative 1e-9 count as equal),
//! then its vertex pair (lower index first), lexicographically. The refinement edge of a tet is
//! its highest-ranked edge (its longest). To bisect an edge e:
//!
//! 1. while some tet around e has a refinement edge e' ≠ e, bisect e' first (recursively; e'
//!    ranks above e, so this ends);
//! 2. put a vertex m at the midpoint of e and split every tet around e into two: (a, b, c, d)
//!    with e = (a, b) becomes (m, b, c, d) and (a, m, c, d).
//!
//! Every tet around e is split at e, so the mesh stays conforming; a child replaces one corner
//! by a point of the segment between two corners, so it has its parent's orientation and half
//! its volume. On a Kuhn grid of cubic cells of size h (edges h, √2 h, √3 h) the longest edges
//! are unique in every tet, and three generations of bisection give Kuhn tets of size h/2: the
//! body diagonal (√3 h), then a face diagonal (√2 h), then a cube edge (h) — the child
//! (x₀, e, f, m) of the corner x₀, the edge's midpoint e, the face's centre f and the cube's
//! centre m is the Kuhn path of the half cell. So a tet refined `3·L` generations is a Kuhn
//! tet of size h/2^L, and the shapes of all tets stay among the three classes of the cycle
//! (Maubach / Freudenthal; the closure bisects neighbours on their own longest edge, so it
//! adds no other shapes).
//!
//! # Marking
//!
//! [`refine_marked`] bisects, pass after pass, every tet that a predicate marks and that is
//! younger than `3·levels` generations, until no such tet is left. The predicate sees the
//! corners and the field values there; a new vertex gets its value from the continuous field,
//! so marking follows the true field, not an interpolation of the coarse samples.

use std::collections::HashMap;

use crate::mesh::TET10_EDGES as TET_EDGES;

/// A refined mesh: every vertex (the input's first, in their order, then the midpoints), the
/// tets (positively oriented if the input's were) with their generation, and every edge once.
#[derive(Clone, Debug, PartialEq)]
pub struct RefinedTets {
    pub positions: Vec<[f64; 3]>,
    pub values: Vec<f64>,
    pub tets: Vec<[usize; 4]>,
    /// Bisections between a tet and its input ancestor (0: an input tet).
    pub generations: Vec<u8>,
    pub edges: Vec<(usize, usize)>,
}

/// What [`refine_marked`] needs to know about one tet to mark it.
pub struct TetView {
    pub corners: [[f64; 3]; 4],
    pub values: [f64; 4],
    pub generation: u8,
    /// The longest edge's length [m].
    pub longest_edge: f64,
}

struct Refiner<'f> {
    positions: Vec<[f64; 3]>,
    values: Vec<f64>,
    tets: Vec<[usize; 4]>,
    generations: Vec<u8>,
    alive: Vec<bool>,
    around: HashMap<(usize, usize), Vec<usize>>,
    midpoints: HashMap<(usize, usize), usize>,
    field: &'f dyn Fn([f64; 3]) -> f64,
}

fn key(a: usize, b: usize) -> (usize, usize) {
    if a < b {
        (a, b)
    } else {
        (b, a)
    }
}

fn length_squared(p: [f64; 3], q: [f64; 3]) -> f64 {
    (0..3).map(|d| (p[d] - q[d]).powi(2)).sum()
}

impl Refiner<'_> {
    fn edge_length_squared(&self, e: (usize, usize)) -> f64 {
        length_squared(self.positions[e.0], self.positions[e.1])
    }

    /// Whether edge `a` ranks above edge `b` (module docs).
    fn ranks_above(&self, a: (usize, usize), b: (usize, usize)) -> bool {
        let (la, lb) = (self.edge_length_squared(a), self.edge_length_squared(b));
        if (la - lb).abs() > 1e-9 * la.max(lb) {
            return la > lb;
        }
        a > b
    }

    fn refinement_edge(&self, t: usize) -> (usize, usize) {
        let v = self.tets[t];
        let mut best = key(v[0], v[1]);
        for &(i, j) in &TET_EDGES[1..] {
            let e = key(v[i], v[j]);
            if self.ranks_above(e, best) {
                best = e;
            }
        }
        best
    }

    fn add_tet(&mut self, tet: [usize; 4], generation: u8) -> usize {
        let t = self.tets.len();
        self.tets.push(tet);
        self.generations.push(generation);
        self.alive.push(true);
        for (i, j) in TET_EDGES {
            self.around.entry(key(tet[i], tet[j])).or_default().push(t);
        }
        t
    }

    fn remove_tet(&mut self, t: usize) {
        self.alive[t] = false;
        let tet = self.tets[t];
        for (i, j) in TET_EDGES {
            let k = key(tet[i], tet[j]);
            if let Some(list) = self.around.get_mut(&k) {
                list.retain(|&u| u != t);
                if list.is_empty() {
                    self.around.remove(&k);
                }
            }
        }
    }

    /// Bisects edge `e` in every tet around it, after making it their refinement edge.
    fn bisect(&mut self, e: (usize, usize)) {
        loop {
            let Some(list) = self.around.get(&e) else {
                return;
            };
            let other = list
                .iter()
                .map(|&t| self.refinement_edge(t))
                .find(|&f| f != e);
            match other {
                Some(f) => self.bisect(f),
                None => break,
            }
        }
        let Some(list) = self.around.get(&e).cloned() else {
            return;
        };
        let m = *self.midpoints.entry(e).or_insert_with(|| {
            let (p, q) = (self.positions[e.0], self.positions[e.1]);
            let x = [0, 1, 2].map(|d| 0.5 * (p[d] + q[d]));
            self.positions.push(x);
            self.values.push((self.field)(x));
            self.positions.len() - 1
        });
        for t in list {
            let tet = self.tets[t];
            let generation = self.generations[t].saturating_add(1);
            self.remove_tet(t);
            for end in [e.0, e.1] {
                let mut child = tet;
                for v in child.iter_mut() {
                    if *v == end {
                        *v = m;
                    }
                }
                self.add_tet(child, generation);
            }
        }
    }

    fn view(&self, t: usize) -> TetView {
        let v = self.tets[t];
        let longest = self.edge_length_squared(self.refinement_edge(t)).sqrt();
        TetView {
            corners: v.map(|i| self.positions[i]),
            values: v.map(|i| self.values[i]),
            generation: self.generations[t],
            longest_edge: longest,
        }
    }
}

/// Refines the mesh (`positions`, `values` at them, `tets`) by bisection (module docs): every
/// tet for which `marked` holds and whose generation is below `3·levels` is bisected, its
/// children marked anew, until none is left. `field` gives the value at a new vertex.
pub fn refine_marked(
    positions: Vec<[f64; 3]>,
    values: Vec<f64>,
    tets: &[[usize; 4]],
    levels: usize,
    field: &dyn Fn([f64; 3]) -> f64,
    marked: &dyn Fn(&TetView) -> bool,
) -> RefinedTets {
    assert_eq!(positions.len(), values.len(), "one value per vertex");
    let max_generation = (3 * levels).min(u8::MAX as usize) as u8;
    let mut r = Refiner {
        positions,
        values,
        tets: Vec::with_capacity(tets.len()),
        generations: Vec::new(),
        alive: Vec::new(),
        around: HashMap::new(),
        midpoints: HashMap::new(),
        field,
    };
    for &t in tets {
        r.add_tet(t, 0);
    }
    // A tet's mark depends on its corners and their values alone, so a tet that a pass left
    // unmarked stays so: each pass looks only at the tets made since the previous one.
    let mut first_unseen = 0;
    loop {
        let todo: Vec<usize> = (first_unseen..r.tets.len())
            .filter(|&t| r.alive[t] && r.generations[t] < max_generation && marked(&r.view(t)))
            .collect();
        first_unseen = r.tets.len();
        if todo.is_empty() {
            break;
        }
        for t in todo {
            if r.alive[t] {
                let e = r.refinement_edge(t);
                r.bisect(e);
            }
        }
    }
    let keep: Vec<usize> = (0..r.tets.len()).filter(|&t| r.alive[t]).collect();
    let mut edges: Vec<(usize, usize)> = r.around.keys().copied().collect();
    edges.sort_unstable();
    RefinedTets {
        tets: keep.iter().map(|&t| r.tets[t]).collect(),
        generations: keep.iter().map(|&t| r.generations[t]).collect(),
        positions: r.positions,
        values: r.values,
        edges,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::signed_tet_volume;

    fn kuhn_box(n: usize, h: f64) -> (Vec<[f64; 3]>, Vec<[usize; 4]>) {
        let mesh = crate::mesh::box_mesh([n; 3], [n as f64 * h; 3]);
        let tets = (0..mesh.n_tets())
            .map(|e| {
                let t = mesh.tet(e);
                [t[0], t[1], t[2], t[3]]
            })
            .collect();
        (mesh.nodes, tets)
    }

    fn volume(r: &RefinedTets, t: usize) -> f64 {
        let v = r.tets[t].map(|i| r.positions[i]);
        signed_tet_volume(v[0], v[1], v[2], v[3])
    }

    /// Every interior face is shared by exactly two tets, and the boundary faces tile the box's
    /// surface: the mesh is conforming.
    fn assert_conforming(r: &RefinedTets, side: f64) {
        let mut faces: HashMap<[usize; 3], usize> = HashMap::new();
        for t in &r.tets {
            for skip in 0..4 {
                let mut f: Vec<usize> = (0..4).filter(|&i| i != skip).map(|i| t[i]).collect();
                f.sort_unstable();
                *faces.entry([f[0], f[1], f[2]]).or_default() += 1;
            }
        }
        let mut boundary_area = 0.0;
        for (f, count) in &faces {
            assert!(*count <= 2, "face {f:?} shared by {count} tets");
            if *count == 1 {
                let [a, b, c] = f.map(|i| r.positions[i]);
                let (u, v) = (
                    [0, 1, 2].map(|d| b[d] - a[d]),
                    [0, 1, 2].map(|d| c[d] - a[d]),
                );
                let n = [
                    u[1] * v[2] - u[2] * v[1],
                    u[2] * v[0] - u[0] * v[2],
                    u[0] * v[1] - u[1] * v[0],
                ];
                boundary_area += 0.5 * (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
                // A boundary face lies on the box's surface.
                let on_surface = (0..3).any(|d| {
                    [a, b, c].iter().all(|p| p[d].abs() < 1e-12)
                        || [a, b, c].iter().all(|p| (p[d] - side).abs() < 1e-12)
                });
                assert!(
                    on_surface,
                    "boundary face {f:?} inside the box: a hanging node"
                );
            }
        }
        assert!(
            (boundary_area - 6.0 * side * side).abs() < 1e-9 * side * side,
            "boundary area {boundary_area}"
        );
    }

    #[test]
    fn refining_a_ball_keeps_the_mesh_conforming_oriented_and_of_the_same_volume() {
        let (n, h) = (6, 1.0);
        let (positions, tets) = kuhn_box(n, h);
        let centre = [3.0, 3.0, 3.0];
        let field = |x: [f64; 3]| 2.0 - length_squared(x, centre).sqrt();
        let values = positions.iter().map(|&x| field(x)).collect();
        // A band around the sphere of radius 2.
        let r = refine_marked(positions, values, &tets, 2, &field, &|v: &TetView| {
            let (lo, hi) = v
                .values
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
                    (a.min(x), b.max(x))
                });
            lo - v.longest_edge <= 0.0 && hi + v.longest_edge >= 0.0
        });
        assert!(r.tets.len() > tets.len());
        let total: f64 = (0..r.tets.len()).map(|t| volume(&r, t)).sum();
        assert!((total - 216.0).abs() < 1e-9, "volume {total}");
        assert!(
            (0..r.tets.len()).all(|t| volume(&r, t) > 0.0),
            "an inverted or flat tet"
        );
        assert_conforming(&r, n as f64 * h);
        // Every edge listed once, and every tet edge among them.
        let listed: std::collections::HashSet<(usize, usize)> = r.edges.iter().copied().collect();
        assert_eq!(listed.len(), r.edges.len());
        for t in &r.tets {
            for (i, j) in TET_EDGES {
                assert!(listed.contains(&key(t[i], t[j])));
            }
        }
    }

    #[test]
    fn three_generations_make_kuhn_tets_of_half_the_size_and_only_three_shapes() {
        let (positions, tets) = kuhn_box(4, 1.0);
        let values = vec![0.0; positions.len()];
        let zero = |_: [f64; 3]| 0.0;
        // Mark the tets with a corner in the lower-left-front quarter, two levels deep.
        let r = refine_marked(positions, values, &tets, 2, &zero, &|v: &TetView| {
            v.corners.iter().any(|c| c.iter().all(|&x| x < 1.5))
        });
        let mut generations_seen = std::collections::BTreeSet::new();
        let mut shapes = std::collections::BTreeSet::new();
        for (t, tet) in r.tets.iter().enumerate() {
            let g = r.generations[t];
            generations_seen.insert(g);
            // Volume halves with each generation: 1/6 of a unit cube at generation 0.
            let expected = 1.0 / 6.0 / 2f64.powi(g as i32);
            assert!(
                (volume(&r, t) - expected).abs() < 1e-12,
                "generation {g}: volume {} against {expected}",
                volume(&r, t)
            );
            if g % 3 == 0 {
                // A Kuhn tet of size 2^(−g/3): edges h, h, h, √2h, √2h, √3h.
                let size = 0.5f64.powi(g as i32 / 3);
                let mut l: Vec<f64> = TET_EDGES
                    .iter()
                    .map(|&(i, j)| {
                        length_squared(r.positions[tet[i]], r.positions[tet[j]]).sqrt() / size
                    })
                    .collect();
                l.sort_by(f64::total_cmp);
                let kuhn = [1.0, 1.0, 1.0, 2f64.sqrt(), 2f64.sqrt(), 3f64.sqrt()];
                assert!(
                    l.iter().zip(kuhn).all(|(a, b)| (a - b).abs() < 1e-12),
                    "generation {g}: edges {l:?}"
                );
            }
            // The shape class: the sorted edge lengths relative to the longest.
            let mut l: Vec<f64> = TET_EDGES
                .iter()
                .map(|&(i, j)| length_squared(r.positions[tet[i]], r.positions[tet[j]]))
                .collect();
            l.sort_by(f64::total_cmp);
            shapes.insert(
                l.iter()
                    .map(|x| (x / l[5] * 1e6).round() as i64)
                    .collect::<Vec<_>>(),
            );
        }
        assert!(
            generations_seen.contains(&6),
            "the marked region reached generation 6: {generations_seen:?}"
        );
        assert!(
            shapes.len() <= 3,
            "{} shape classes: {shapes:?}",
            shapes.len()
        );
        let total: f64 = (0..r.tets.len()).map(|t| volume(&r, t)).sum();
        assert!((total - 64.0).abs() < 1e-9);
        assert_conforming(&r, 4.0);
    }

    #[test]
    fn new_vertices_take_the_continuous_field_and_nothing_marked_changes_nothing() {
        let (positions, tets) = kuhn_box(2, 1.0);
        let field = |x: [f64; 3]| x[0] * x[0] + 2.0 * x[1] - x[2];
        let values: Vec<f64> = positions.iter().map(|&x| field(x)).collect();
        let same = refine_marked(
            positions.clone(),
            values.clone(),
            &tets,
            3,
            &field,
            &|_: &TetView| false,
        );
        assert_eq!(same.tets, tets);
        assert_eq!(same.positions, positions);
        let r = refine_marked(
            positions.clone(),
            values.clone(),
            &tets,
            1,
            &field,
            &|_: &TetView| true,
        );
        assert_eq!(
            r.tets.len(),
            8 * tets.len(),
            "one level everywhere: every tet into eight"
        );
        assert_eq!(&r.positions[..positions.len()], &positions[..]);
        for (x, v) in r.positions.iter().zip(&r.values) {
            assert_eq!(*v, field(*x));
        }
        // One level everywhere is the 4-cell Kuhn grid of half the size: 5³ vertices.
        assert_eq!(r.positions.len(), 125);
    }
}
