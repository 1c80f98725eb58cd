//! Tests of the light tree: its probabilities against its samples, walks side by side, χ², cones.

use super::bounds::{cone_around, cone_union};
use super::*;
use crate::math::det;
use crate::testing::uniform_stream;
use glam::Vec3;

/// `count` random triangles in a 10 m box, some two-sided, powers from 0.1 to 10 (normalised).
fn random_lights(count: usize, seed: u64) -> Vec<LightBounds> {
    let mut u = uniform_stream(seed);
    let mut point = |s: f32| Vec3::new(u() * s, u() * s, u() * s);
    let mut lights: Vec<LightBounds> = (0..count)
        .map(|i| {
            let a = point(10.0);
            let c = [a, a + point(0.5), a + point(0.5)];
            let n = (c[1] - c[0]).cross(c[2] - c[0]).normalize();
            LightBounds::triangle(c, n, 0.1 + 10.0 * (i % 7) as f32, i % 5 == 0)
        })
        .collect();
    let total: f32 = lights.iter().map(|l| l.phi).sum();
    for l in &mut lights {
        l.phi /= total;
    }
    lights
}

#[test]
fn probabilities_sum_to_at_most_one_and_match_the_sampled_ones() {
    let lights = random_lights(300, 1);
    let tree = LightTree::new(&lights);
    assert!(
        tree.node_count() <= lights.len() / 2,
        "{} nodes",
        tree.node_count()
    );
    let mut u = uniform_stream(2);
    let mut whole = 0.0;
    for _ in 0..200 {
        let p = Vec3::new(u() * 14.0 - 2.0, u() * 14.0 - 2.0, u() * 14.0 - 2.0);
        let n = Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize();
        let total: f64 = (0..lights.len()).map(|k| tree.pmf(p, n, k) as f64).sum();
        // At most 1: a node may be chosen whose children all are out of reach.
        assert!(total > 0.8 && total < 1.0 + 1e-4, "Σ pmf = {total} at {p}");
        whole += total;
        for _ in 0..20 {
            if let Some((k, pmf)) = tree.sample(p, n, u()) {
                assert!(pmf > 0.0);
                assert_eq!(pmf.to_bits(), tree.pmf(p, n, k).to_bits());
            }
        }
    }
    // Little is wasted: 1 % at the median point of this cloud of randomly facing lights.
    assert!(whole / 200.0 > 0.95, "mean Σ pmf {}", whole / 200.0);
}

/// Walks side by side choose what each alone chooses, with the same probabilities, bit for
/// bit, the walks of different lengths, ending at no light or at one.
#[test]
fn walks_side_by_side_choose_what_each_alone_chooses() {
    let lights = random_lights(500, 3);
    let tree = LightTree::new(&lights);
    let mut u = uniform_stream(4);
    let mut query = || {
        let p = Vec3::new(u() * 14.0 - 2.0, u() * 14.0 - 2.0, u() * 14.0 - 2.0);
        let n = Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize();
        // Some points far off and facing away from everything, where walks end early.
        let p = if u() < 0.1 { p * 1e3 } else { p };
        (p, n, u())
    };
    let (mut found, mut none) = (0, 0);
    for _ in 0..2000 {
        let queries: [(Vec3, Vec3, f32); 3] = [query(), query(), query()];
        let alone = queries.map(|(p, n, u)| tree.sample(p, n, u));
        let bits = |c: Option<(usize, f32)>| c.map(|(k, pmf)| (k, pmf.to_bits()));
        assert_eq!(tree.sample_many(queries).map(bits), alone.map(bits));
        let pair = tree.sample_many([queries[0], queries[2]]);
        assert_eq!(pair.map(bits), [bits(alone[0]), bits(alone[2])]);
        found += alone.iter().filter(|c| c.is_some()).count();
        none += alone.iter().filter(|c| c.is_none()).count();
    }
    assert!(found > 1000 && none > 0, "{found} found, {none} none");
    assert_eq!(LightTree::new(&[]).sample_many([query(); 2]), [None, None]);
}

/// Pearson's χ² of the lights chosen at a point against [`LightTree::pmf`], lights of small
/// expected counts pooled.
#[test]
fn chosen_lights_follow_the_pmf() {
    let lights = random_lights(64, 3);
    let tree = LightTree::new(&lights);
    let mut u = uniform_stream(4);
    for &(p, n) in &[
        (Vec3::new(5.0, 5.0, 5.0), Vec3::Y),
        (Vec3::new(-3.0, 1.0, 12.0), Vec3::ZERO),
        (Vec3::new(9.0, 0.2, 3.0), Vec3::X),
    ] {
        let draws = 200_000;
        let mut counts = vec![0u32; lights.len()];
        let mut none = 0u32;
        for _ in 0..draws {
            match tree.sample(p, n, u()) {
                Some((k, _)) => counts[k] += 1,
                None => none += 1,
            }
        }
        // No light chosen is a cell of its own, of probability 1 − Σ pmf.
        let total: f64 = (0..lights.len()).map(|k| tree.pmf(p, n, k) as f64).sum();
        let e_none = (1.0 - total).max(0.0) * draws as f64;
        let (mut chi2, mut dof) = (0.0f64, 0usize);
        let (mut pooled_e, mut pooled_o) = (e_none, none as f64);
        for (k, &c) in counts.iter().enumerate() {
            let e = tree.pmf(p, n, k) as f64 * draws as f64;
            if e < 5.0 {
                assert!(e > 0.0 || c == 0, "light {k} drawn with pmf 0");
                (pooled_e, pooled_o) = (pooled_e + e, pooled_o + c as f64);
                continue;
            }
            chi2 += (c as f64 - e).powi(2) / e;
            dof += 1;
        }
        if pooled_e > 0.0 {
            chi2 += (pooled_o - pooled_e).powi(2) / pooled_e.max(1.0);
            dof += 1;
        }
        // The 99.9th percentile of χ² with dof − 1 degrees of freedom (Wilson–Hilferty).
        let k = (dof - 1) as f64;
        let z = 3.09;
        let limit = k * (1.0 - 2.0 / (9.0 * k) + z * (2.0 / (9.0 * k)).sqrt()).powi(3);
        assert!(
            chi2 < limit,
            "χ² {chi2:.1} ≥ {limit:.1} ({dof} cells) at {p}"
        );
    }
}

#[test]
fn a_point_behind_every_one_sided_light_gets_none_and_a_lit_one_gets_the_near_light_mostly() {
    // Two small lights facing +z at z = 0, one near the receiver, one far.
    let quad = |x: f32| {
        let c = [
            Vec3::new(x, 0.0, 0.0),
            Vec3::new(x + 0.1, 0.0, 0.0),
            Vec3::new(x, 0.1, 0.0),
        ];
        LightBounds::triangle(c, Vec3::Z, 0.5, false)
    };
    let tree = LightTree::new(&[quad(0.0), quad(20.0)]);
    assert_eq!(
        tree.sample(Vec3::new(0.0, 0.0, -1.0), Vec3::ZERO, 0.5),
        None
    );
    assert_eq!(tree.pmf(Vec3::new(0.0, 0.0, -1.0), Vec3::ZERO, 0), 0.0);
    let near = tree.pmf(Vec3::new(0.0, 0.0, 1.0), -Vec3::Z, 0);
    assert!(near > 0.99, "near light's probability {near}");
    // A receiver facing away still gets both (the receiver cosine is folded: glass transmits).
    assert!(tree.pmf(Vec3::new(0.0, 0.0, 1.0), Vec3::Z, 1) > 0.0);
}

#[test]
fn the_tree_is_the_same_whatever_the_input_order_of_equal_lights_and_stays_shallow() {
    // 5,000 lights on one point with one normal: no split separates them; halving does.
    let c = [Vec3::ZERO, Vec3::X * 1e-3, Vec3::Y * 1e-3];
    let lights = vec![LightBounds::triangle(c, Vec3::Z, 1.0 / 5000.0, false); 5000];
    let tree = LightTree::new(&lights);
    // Thirteen binary levels, at least two per 4-wide level but the last: seven, two bits each.
    let deepest = tree.trails.iter().map(|t| 128 - t.leading_zeros()).max();
    assert!(deepest <= Some(14), "trail bits {deepest:?}");
    let p = Vec3::new(0.3, 0.1, 1.0);
    assert!((tree.pmf(p, Vec3::ZERO, 17) - 1.0 / 5000.0).abs() < 1e-7);
}

#[test]
fn cones_hold_their_members() {
    let mut u = uniform_stream(9);
    for _ in 0..1000 {
        let mut dir = || Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize();
        let (a, b) = (dir(), dir());
        let (w, cos) = cone_union((a, 1.0), (b, 1.0));
        assert!(w.dot(a) >= cos && w.dot(b) >= cos, "{a} {b} → {w} {cos}");
        let members = [(a, 1.0), (b, 1.0), (dir(), 0.9)];
        let (w, cos) = cone_around(members.iter().copied());
        for (m, cos_m) in members {
            // Member m's cone is within the union: angle(w, m) + θm ≤ θ.
            let angle = det::acos(w.dot(m).clamp(-1.0, 1.0)) + det::acos(cos_m);
            assert!(cos <= -1.0 || angle <= det::acos(cos) + 1e-5);
        }
    }
}
