//! Node partition: which rank owns which mesh node (and so which matrix rows).
//!
//! Recursive coordinate bisection (RCB): split the node cloud at the median of its longest axis,
//! proportionally to the number of parts on each side, until there is one part per rank. RCB
//! gives compact parts with short interfaces, which keeps the off-rank coupling (and the MUMPS
//! interface fronts) small. Ties are broken by node index, so every rank computes the same
//! partition without communicating.
//!
//! Why not a graph partitioner: Debian's PETSc has no METIS/ParMETIS but does have PT-Scotch
//! (`MatPartitioning` type `ptscotch`). RCB is kept because it needs only the coordinates, so
//! the partition exists before any matrix or node graph is built (the layout decides which rank
//! assembles which rows), and it is deterministic and free of communication. Whether PT-Scotch
//! would cut shorter interfaces on our meshes has not been measured.
//!
//! Nodes are renumbered so that rank `r` owns the contiguous range `offsets[r]..offsets[r+1]`;
//! inside a part the original relative order is kept (mesh generators number nodes locally).

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NodePartition {
    /// New (PETSc-order) index of each original node.
    pub new_of_old: Vec<usize>,
    /// Original index of each new node.
    pub old_of_new: Vec<usize>,
    /// `offsets[r]..offsets[r+1]` are the new node indices owned by rank `r`.
    pub offsets: Vec<usize>,
}

impl NodePartition {
    pub fn n_parts(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Owning rank of a node given by its NEW index.
    pub fn owner_of_new(&self, new: usize) -> usize {
        // offsets is sorted; partition_point gives the first offset > new.
        self.offsets.partition_point(|&o| o <= new) - 1
    }

    pub fn owned_range(&self, rank: usize) -> std::ops::Range<usize> {
        self.offsets[rank]..self.offsets[rank + 1]
    }
}

/// Partitions `nodes` into `n_parts` compact, near-equal parts by RCB.
pub fn partition_nodes(nodes: &[[f64; 3]], n_parts: usize) -> NodePartition {
    assert!(n_parts >= 1);
    let mut parts: Vec<Vec<usize>> = Vec::with_capacity(n_parts);
    bisect(nodes, (0..nodes.len()).collect(), n_parts, &mut parts);
    let mut old_of_new = Vec::with_capacity(nodes.len());
    let mut offsets = vec![0];
    for mut part in parts {
        part.sort_unstable();
        old_of_new.extend_from_slice(&part);
        offsets.push(old_of_new.len());
    }
    let mut new_of_old = vec![0; nodes.len()];
    for (new, &old) in old_of_new.iter().enumerate() {
        new_of_old[old] = new;
    }
    NodePartition {
        new_of_old,
        old_of_new,
        offsets,
    }
}

fn bisect(nodes: &[[f64; 3]], mut ids: Vec<usize>, n_parts: usize, out: &mut Vec<Vec<usize>>) {
    if n_parts == 1 || ids.len() <= 1 {
        out.push(ids);
        // Parts beyond the node count stay empty but present, so offsets has n_parts + 1 entries.
        for _ in 1..n_parts {
            out.push(Vec::new());
        }
        return;
    }
    let left_parts = n_parts / 2;
    let axis = longest_axis(nodes, &ids);
    let split = ids.len() * left_parts / n_parts;
    let key = |&i: &usize| (nodes[i][axis], i);
    ids.select_nth_unstable_by(split, |a, b| {
        key(a)
            .partial_cmp(&key(b))
            .unwrap_or(std::cmp::Ordering::Equal)
    });
    let right = ids.split_off(split);
    bisect(nodes, ids, left_parts, out);
    bisect(nodes, right, n_parts - left_parts, out);
}

fn longest_axis(nodes: &[[f64; 3]], ids: &[usize]) -> usize {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &i in ids {
        for d in 0..3 {
            lo[d] = lo[d].min(nodes[i][d]);
            hi[d] = hi[d].max(nodes[i][d]);
        }
    }
    (0..3)
        .max_by(|&a, &b| {
            (hi[a] - lo[a])
                .partial_cmp(&(hi[b] - lo[b]))
                .unwrap_or(std::cmp::Ordering::Equal)
        })
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(n: usize) -> Vec<[f64; 3]> {
        // Deterministic pseudo-random points in a 3 × 1 × 1 box.
        let mut s = 12345u64;
        let mut r = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..n).map(|_| [3.0 * r(), r(), r()]).collect()
    }

    #[test]
    fn partition_is_a_balanced_permutation() {
        let pts = cloud(1001);
        for parts in 1..=5 {
            let p = partition_nodes(&pts, parts);
            assert_eq!(p.n_parts(), parts);
            let mut seen = p.old_of_new.clone();
            seen.sort_unstable();
            assert_eq!(seen, (0..pts.len()).collect::<Vec<_>>());
            for (old, &new) in p.new_of_old.iter().enumerate() {
                assert_eq!(p.old_of_new[new], old);
            }
            let sizes: Vec<usize> = (0..parts).map(|r| p.owned_range(r).len()).collect();
            let (mn, mx) = (*sizes.iter().min().unwrap(), *sizes.iter().max().unwrap());
            assert!(mx - mn <= 1 + parts, "unbalanced {sizes:?}");
            for r in 0..parts {
                for new in p.owned_range(r) {
                    assert_eq!(p.owner_of_new(new), r);
                }
            }
        }
    }

    #[test]
    fn two_parts_split_the_longest_axis() {
        let pts = cloud(500);
        let p = partition_nodes(&pts, 2);
        let max_left = p
            .owned_range(0)
            .map(|n| pts[p.old_of_new[n]][0])
            .fold(f64::MIN, f64::max);
        let min_right = p
            .owned_range(1)
            .map(|n| pts[p.old_of_new[n]][0])
            .fold(f64::MAX, f64::min);
        assert!(max_left <= min_right);
    }

    #[test]
    fn more_parts_than_nodes_is_allowed() {
        let p = partition_nodes(&cloud(2), 4);
        assert_eq!(p.n_parts(), 4);
        assert_eq!(*p.offsets.last().unwrap(), 2);
    }
}
