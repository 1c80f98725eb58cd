//! GGX visible normals: sampled by D_wo(m), against an independent f64 reference.

use super::*;

/// Independent f64 reference: D_o(m) = G1(o) max(0, o·m) D(m) / o.z.
fn reference_vndf(alpha: f64, o: DVec3, m: DVec3) -> f64 {
    if m.z <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let cos2 = m.z * m.z;
    let tan2 = (m.x * m.x + m.y * m.y) / cos2;
    let d = 1.0 / (PI * a2 * cos2 * cos2 * (1.0 + tan2 / a2).powi(2));
    let tan2_o = (1.0 - o.z * o.z) / (o.z * o.z);
    let lambda = 0.5 * ((1.0 + a2 * tan2_o).sqrt() - 1.0);
    let g1 = 1.0 / (1.0 + lambda);
    g1 * o.dot(m).max(0.0) * d / o.z
}

#[test]
fn ggx_visible_normal_sampling_matches_d_wo() {
    let mut failures = Vec::new();
    for (ai, &alpha) in [0.0025f32, 0.09, 0.5, 1.0].iter().enumerate() {
        for (ci, &cos) in [0.95f32, 0.5, 0.1, 0.02].iter().enumerate() {
            let g = Ggx { alpha };
            let o = wo_at(cos, true);
            let s = alpha as f64;
            let bins = Binning::Zoom(Box::new((
                HemiGrid::new(true, DVec3::Z, s, 32, 32),
                HemiGrid::new(false, -DVec3::Z, s, 4, 4),
            )));
            let mut observed = vec![0.0f64; bins.len()];
            let mut rng = Pcg32::new((ai * 10 + ci) as u64, 3);
            let n = 1_000_000;
            for _ in 0..n {
                let m = g.sample_visible_normal(o, Vec2::new(rng.f32(), rng.f32()));
                assert!((m.length() - 1.0).abs() < 1e-4 && m.z >= 0.0);
                observed[bins.bin(m).unwrap()] += 1.0;
            }
            let expected: Vec<f64> = bins
                .integrate(
                    |m| reference_vndf(alpha as f64, o.as_dvec3(), m.as_dvec3().normalize()),
                    &observed,
                )
                .iter()
                .map(|e| e * n as f64)
                .collect();
            let total: f64 = expected.iter().sum::<f64>() / n as f64;
            let chi = chi_square_test(&observed, &expected, 5.0);
            println!(
                "VNDF α {alpha:<6} cos {cos:<4}: p = {:.4} (dof {}), ∫ D_wo = {total:.5}",
                chi.p_value, chi.dof
            );
            // The library's own pdf agrees with the reference.
            for k in 0..100 {
                let m = g.sample_visible_normal(o, Vec2::new(k as f32 / 100.0 + 0.003, 0.37));
                let r = reference_vndf(alpha as f64, o.as_dvec3(), m.as_dvec3());
                assert!(((g.visible_normal_pdf(o, m) as f64 - r) / r).abs() < 1e-3);
            }
            if chi.p_value <= MIN_P || (total - 1.0).abs() > 5e-3 {
                failures.push((alpha, cos, chi.p_value, total));
            }
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}
