//! Which triangles of a flat mesh share a packet, so that a ray can skip the packets whose box it
//! misses.
//!
//! In the tree's order each of the Cornell box's two packets held walls, so both packets' boxes
//! were the whole room and every ray tested all 32 triangles. Grouped here, the walls and the light
//! share one packet and each block has its own, with a box a ray misses most of the time.
//!
//! The grouping is a small top-down split, as a BVH builder's: a group is split at the best place
//! in one of four orders (the triangles' centroids along x, y or z, or their boxes' areas, largest
//! first, which puts walls apart from the small things in the room), at the cost of the surface
//! area of each part's box (how likely a ray is to meet it) times the packets it fills. A group of
//! more than a packet must be split, without using more packets than it fills; after that, groups
//! are split further while that lowers the cost by a tenth and packets are left.

use glam::Vec3;

/// The groups of `triangles` (indices into it, ascending within a group), each of at most `wide`
/// triangles, at most `max_groups` of them (at least as many as the triangles need), the group
/// with the largest box first.
pub(super) fn groups(triangles: &[[Vec3; 3]], wide: usize, max_groups: usize) -> Vec<Vec<u32>> {
    let all: Vec<u32> = (0..triangles.len() as u32).collect();
    let mut groups = Vec::new();
    split_to_fit(triangles, all, wide, &mut groups);
    while groups.len() < max_groups {
        let mut best: Option<(usize, f32, Split)> = None;
        for (i, g) in groups.iter().enumerate() {
            let Some(split) = best_split(triangles, g, wide, false) else {
                continue;
            };
            let gain = area(triangles, g) - split.cost;
            if gain > 0.1 * area(triangles, g) && best.as_ref().is_none_or(|b| gain > b.1) {
                best = Some((i, gain, split));
            }
        }
        let Some((i, _, split)) = best else { break };
        groups[i] = split.left;
        groups.push(split.right);
    }
    for g in &mut groups {
        g.sort_unstable();
    }
    // Largest box first: a closest-hit query that tests it first has a nearer best distance with
    // which to skip the small boxes behind it. (`total_cmp`: boxes of huge coordinates may have an
    // infinite area.)
    groups.sort_by(|a, b| area(triangles, b).total_cmp(&area(triangles, a)));
    groups
}

/// A group split in two, and the cost of the two parts.
struct Split {
    left: Vec<u32>,
    right: Vec<u32>,
    cost: f32,
}

/// Splits `group` until every part fits a packet, appending the parts to `out`.
fn split_to_fit(triangles: &[[Vec3; 3]], group: Vec<u32>, wide: usize, out: &mut Vec<Vec<u32>>) {
    if group.len() <= wide {
        out.push(group);
        return;
    }
    let split = best_split(triangles, &group, wide, true).expect("a group over a packet splits");
    split_to_fit(triangles, split.left, wide, out);
    split_to_fit(triangles, split.right, wide, out);
}

/// The cheapest split of `group` into two non-empty parts; with `keep_packets`, only splits whose
/// parts fill no more packets than the group does.
fn best_split(
    triangles: &[[Vec3; 3]],
    group: &[u32],
    wide: usize,
    keep_packets: bool,
) -> Option<Split> {
    let packets = |n: usize| n.div_ceil(wide);
    let mut best: Option<(f32, Vec<u32>, usize)> = None;
    for key in 0..4 {
        let mut order = group.to_vec();
        let key_of = |id: u32| {
            let t = &triangles[id as usize];
            match key {
                3 => -bounds_area(bounds(std::slice::from_ref(t))),
                axis => (t[0][axis] + t[1][axis] + t[2][axis]) / 3.0,
            }
        };
        order.sort_by(|&a, &b| key_of(a).total_cmp(&key_of(b)).then(a.cmp(&b)));
        // The box of every prefix and of every suffix of the order.
        let n = order.len();
        let tri = |i: usize| triangles[order[i] as usize];
        let mut prefix = Vec::with_capacity(n);
        let mut suffix = vec![EMPTY; n];
        let mut acc = EMPTY;
        for i in 0..n {
            acc = union(acc, bounds(&[tri(i)]));
            prefix.push(acc);
        }
        acc = EMPTY;
        for i in (0..n).rev() {
            acc = union(acc, bounds(&[tri(i)]));
            suffix[i] = acc;
        }
        for k in 1..n {
            if keep_packets && packets(k) + packets(n - k) > packets(n) {
                continue;
            }
            let cost = bounds_area(prefix[k - 1]) * packets(k) as f32
                + bounds_area(suffix[k]) * packets(n - k) as f32;
            // The first candidate is taken even when every cost is infinite or NaN
            // (coordinates whose products overflow); `total_cmp` orders NaN above the rest.
            if best.as_ref().is_none_or(|b| cost.total_cmp(&b.0).is_lt()) {
                best = Some((cost, order.clone(), k));
            }
        }
    }
    best.map(|(cost, order, k)| Split {
        left: order[..k].to_vec(),
        right: order[k..].to_vec(),
        cost,
    })
}

/// An axis-aligned box as (lower, upper) corners.
type Bounds = (Vec3, Vec3);

const EMPTY: Bounds = (Vec3::INFINITY, Vec3::NEG_INFINITY);

fn union(a: Bounds, b: Bounds) -> Bounds {
    (a.0.min(b.0), a.1.max(b.1))
}

/// The box of the triangles.
pub(super) fn bounds(triangles: &[[Vec3; 3]]) -> Bounds {
    triangles
        .iter()
        .flatten()
        .fold(EMPTY, |b, &v| union(b, (v, v)))
}

fn bounds_area((lo, hi): Bounds) -> f32 {
    let e = (hi - lo).max(Vec3::ZERO);
    2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
}

/// The box of the triangles `group` names.
pub(super) fn bounds_of(triangles: &[[Vec3; 3]], group: &[u32]) -> Bounds {
    group.iter().fold(EMPTY, |b, &i| {
        union(b, bounds(std::slice::from_ref(&triangles[i as usize])))
    })
}

/// The surface area of the box of the triangles `group` names.
fn area(triangles: &[[Vec3; 3]], group: &[u32]) -> f32 {
    bounds_area(bounds_of(triangles, group))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The six faces of the axis-aligned box from `lo` to `hi` as twelve triangles (their
    /// winding does not matter here).
    fn box_faces(lo: Vec3, hi: Vec3) -> Vec<[Vec3; 3]> {
        let c = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
        let (a, b) = (lo, hi);
        let quads = [
            [
                c(a.x, a.y, a.z),
                c(b.x, a.y, a.z),
                c(b.x, b.y, a.z),
                c(a.x, b.y, a.z),
            ],
            [
                c(a.x, a.y, b.z),
                c(b.x, a.y, b.z),
                c(b.x, b.y, b.z),
                c(a.x, b.y, b.z),
            ],
            [
                c(a.x, a.y, a.z),
                c(a.x, b.y, a.z),
                c(a.x, b.y, b.z),
                c(a.x, a.y, b.z),
            ],
            [
                c(b.x, a.y, a.z),
                c(b.x, b.y, a.z),
                c(b.x, b.y, b.z),
                c(b.x, a.y, b.z),
            ],
            [
                c(a.x, a.y, a.z),
                c(b.x, a.y, a.z),
                c(b.x, a.y, b.z),
                c(a.x, a.y, b.z),
            ],
            [
                c(a.x, b.y, a.z),
                c(b.x, b.y, a.z),
                c(b.x, b.y, b.z),
                c(a.x, b.y, b.z),
            ],
        ];
        quads
            .iter()
            .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
            .collect()
    }

    /// A room (twelve wall triangles) holding two small blocks of ten triangles each (one face
    /// left out), shuffled together: the walls go to one packet, each block to one of
    /// its own.
    #[test]
    fn a_room_with_two_blocks_gets_a_packet_per_block() {
        let room = box_faces(Vec3::ZERO, Vec3::splat(10.0));
        let block = |lo: Vec3| box_faces(lo, lo + Vec3::splat(2.0))[2..].to_vec();
        let (a, b) = (
            block(Vec3::new(1.0, 0.0, 1.0)),
            block(Vec3::new(6.0, 0.0, 6.0)),
        );
        let mut tris: Vec<[Vec3; 3]> = Vec::new();
        for i in 0..12 {
            tris.push(room[i]);
            if i < 10 {
                tris.push(a[i]);
                tris.push(b[i]);
            }
        }
        let groups = groups(&tris, 16, 4);
        assert_eq!(groups.len(), 3, "{groups:?}");
        let mut all: Vec<u32> = groups.concat();
        all.sort_unstable();
        assert_eq!(all, (0..32).collect::<Vec<u32>>(), "every triangle once");
        for g in &groups {
            assert!(g.windows(2).all(|w| w[0] < w[1]), "ascending: {g:?}");
        }
        // The first group's box is the room; the others are the blocks' (one each, with the
        // room's four leftover triangles of neither block placed where they cost least).
        let boxes: Vec<Bounds> = groups.iter().map(|g| bounds_of(&tris, g)).collect();
        assert_eq!(boxes[0], (Vec3::ZERO, Vec3::splat(10.0)));
        let mut small: Vec<Bounds> = boxes[1..].to_vec();
        small.sort_by(|p, q| p.0.x.total_cmp(&q.0.x));
        assert_eq!(
            small[0],
            (Vec3::new(1.0, 0.0, 1.0), Vec3::new(3.0, 2.0, 3.0))
        );
        assert_eq!(
            small[1],
            (Vec3::new(6.0, 0.0, 6.0), Vec3::new(8.0, 2.0, 8.0))
        );
    }

    /// Groups never exceed a packet or the packet budget, and a budget of the packets the
    /// triangles need leaves no room for optional splits.
    #[test]
    fn groups_respect_the_packet_size_and_budget() {
        let mut rng = crate::testing::uniform_stream(7);
        for n in 1..=64usize {
            let tris: Vec<[Vec3; 3]> = (0..n)
                .map(|_| [(); 3].map(|_| Vec3::new(rng(), rng(), rng()) * 4.0))
                .collect();
            for max in [n.div_ceil(16), 4] {
                let g = groups(&tris, 16, max.max(n.div_ceil(16)));
                assert!(g.len() <= max.max(n.div_ceil(16)) && g.len() >= n.div_ceil(16));
                assert!(g.iter().all(|g| !g.is_empty() && g.len() <= 16));
                let mut all: Vec<u32> = g.concat();
                all.sort_unstable();
                assert_eq!(all, (0..n as u32).collect::<Vec<u32>>());
            }
        }
    }
}
