//! Energy: white furnaces, refraction's radiance scaling, exact Fresnel, no leaks.

use super::*;

/// Mean and standard error of the BSDF weights (rejected samples count as 0), per channel. With
/// `flux`, a refracted weight is multiplied by (n_i / n_o)², undoing the radiance scaling.
fn furnace(p: PbrParams, wo: Vec3, n: usize, seed: u64, flux: bool) -> (Vec3, Vec3) {
    let b = bsdf(p);
    let mut rng = Pcg32::new(seed, 11);
    let (mut sum, mut sum2) = (DVec3::ZERO, DVec3::ZERO);
    let ratio2 = if wo.z > 0.0 {
        p.ior * p.ior
    } else {
        1.0 / (p.ior * p.ior)
    };
    for _ in 0..n {
        let Some(s) = b.sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32())) else {
            continue;
        };
        let mut w = s.weight.as_dvec3();
        if flux && s.transmitted && !p.thin_walled {
            w *= ratio2 as f64;
        }
        sum += w;
        sum2 += w * w;
    }
    let mean = sum / n as f64;
    let var = (sum2 / n as f64 - mean * mean).max(DVec3::ZERO);
    (mean.as_vec3(), (var / n as f64).as_vec3().map(f32::sqrt))
}

#[test]
fn white_furnace_never_creates_energy() {
    let white = Vec3::ONE;
    let mixed = PbrParams {
        base_color: white,
        metallic: 0.3,
        roughness: 0.5,
        specular: 0.7,
        specular_color: Vec3::ONE,
        ior: 1.4,
        transmission: 0.5,
        thin_walled: false,
        ..PbrParams::diffuse(Vec3::ZERO)
    };
    let mut configs: Vec<(String, PbrParams, bool)> =
        vec![("diffuse".into(), PbrParams::diffuse(white), true)];
    for r in [0.0f32, 0.05, 0.3, 0.6, 1.0] {
        configs.push((format!("metal r={r}"), metal(white, r), true));
        configs.push((format!("plastic r={r}"), plastic(white, r), true));
    }
    for r in [0.0f32, 0.05, 0.3, 1.0] {
        configs.push((format!("glass r={r}"), glass(white, r, false), false));
        configs.push((format!("thin glass r={r}"), glass(white, r, true), false));
    }
    configs.push(("mixed r=0.5".into(), mixed, false));
    let mut failures = Vec::new();
    for (k, (name, p, front_only)) in configs.iter().enumerate() {
        let sides: &[bool] = if *front_only { &[true] } else { &[true, false] };
        for &front in sides {
            let mut line = format!("{name:<18} {}:", if front { "front" } else { "back " });
            for (ci, &c) in [1.0f32, 0.9, 0.7, 0.5, 0.3, 0.15, 0.05, 0.02]
                .iter()
                .enumerate()
            {
                let wo = wo_at(c, front);
                let seed = (k * 100 + ci * 2 + front as usize) as u64;
                let (mean, se) = furnace(*p, wo, 400_000, seed, true);
                let m = mean.max_element();
                let bound = 1.0 + 1e-3 + 4.0 * se.max_element();
                line += &format!(" {m:.4}");
                if m > bound {
                    failures.push(format!("{name} front={front} cos={c}: {mean} ± {se}"));
                }
                // The opaque dielectric hands the diffuse exactly what the specular layer leaves, up to
                // the conservative margin of the albedo tables.
                if name.starts_with("plastic") && m < 0.97 - 4.0 * se.max_element() {
                    failures.push(format!("{name} cos={c}: loses energy: {mean}"));
                }
            }
            println!("{line}");
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

#[test]
fn radiance_scaling_of_refraction_is_one_over_eta_squared() {
    // From inside, the raw furnace exceeds 1 (radiance gains ior² leaving the glass along the path's
    // reverse); flux-weighted it is 1 for the smooth dielectric, whose interface loses nothing.
    let p = glass(Vec3::ONE, 0.0, false);
    for front in [true, false] {
        for c in [1.0f32, 0.8, 0.5] {
            let wo = wo_at(c, front);
            let (raw, _) = furnace(p, wo, 100_000, 5, false);
            let (flux, _) = furnace(p, wo, 100_000, 5, true);
            let f = fresnel_ref(c as f64, if front { 1.5 } else { 1.0 / 1.5 });
            let eta2 = if front { 2.25 } else { 1.0 / 2.25 };
            println!(
                "smooth glass front={front} cos {c}: raw {:.4} (expected ≈ {:.4}), flux {:.4}",
                raw.x,
                f + (1.0 - f) / eta2,
                flux.x
            );
            assert!((flux.x as f64 - 1.0).abs() < 1e-5);
            assert!((raw.x as f64 - (f + (1.0 - f) / eta2)).abs() < 0.01);
        }
    }
}

/// Independent f64 reference of the exact unpolarised Fresnel reflectance (eta = n_t / n_i).
fn fresnel_ref(cos_i: f64, eta: f64) -> f64 {
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    0.5 * (rs * rs + rp * rp)
}

#[test]
fn smooth_dielectric_reflects_the_exact_fresnel_fraction() {
    let p = glass(Vec3::ONE, 0.0, false);
    let b = bsdf(p);
    let n = 200_000;
    // Critical angle from inside: cos θc = √(1 − 1/1.5²) ≈ 0.745.
    for (front, c) in [
        (true, 1.0f32),
        (true, 0.8),
        (true, 0.5),
        (true, 0.2),
        (true, 0.05),
        (false, 1.0),
        (false, 0.9),
        (false, 0.8),
        (false, 0.76),
        (false, 0.73),
        (false, 0.5),
        (false, 0.1),
    ] {
        let wo = wo_at(c, front);
        let eta = if front { 1.5 } else { 1.0 / 1.5 };
        let f = fresnel_ref(c as f64, eta);
        let mut rng = Pcg32::new(c.to_bits() as u64, front as u64);
        let mut reflected = 0usize;
        for _ in 0..n {
            let s = b
                .sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32()))
                .expect("smooth glass always scatters");
            assert!(s.delta);
            if s.transmitted {
                // Snell's law and the 1/η² radiance scaling.
                let sin_o = (1.0 - c * c).sqrt();
                let sin_i = (1.0 - s.wi.z * s.wi.z).max(0.0).sqrt();
                assert!(
                    (sin_o - eta as f32 * sin_i).abs() < 1e-4,
                    "Snell: {sin_o} vs {eta} · {sin_i}"
                );
                assert!((s.weight.x - (1.0 / (eta * eta)) as f32).abs() < 1e-4 * s.weight.x);
            } else {
                reflected += 1;
                assert!((s.wi - Vec3::new(-wo.x, -wo.y, wo.z)).length() < 1e-5);
                assert!((s.weight.x - 1.0).abs() < 1e-4);
            }
        }
        let frac = reflected as f64 / n as f64;
        let sigma = (f * (1.0 - f) / n as f64).sqrt();
        println!("smooth dielectric front={front} cos {c:<4}: reflected {frac:.5}, Fresnel {f:.5} (σ {sigma:.1e})");
        if f == 1.0 {
            assert_eq!(reflected, n, "total internal reflection");
        } else {
            assert!(
                (frac - f).abs() <= 5.0 * sigma + 1e-6,
                "front={front} cos={c}: {frac} vs {f}"
            );
        }
    }
    // Thin walls: the transmitted ray goes straight through with weight 1 − F.
    let thin = bsdf(glass(Vec3::ONE, 0.0, true));
    let wo = wo_at(0.5, true);
    let f = fresnel_ref(0.5, 1.5);
    let mut rng = Pcg32::new(3, 3);
    let (mut t, mut total) = (0usize, 0.0f64);
    for _ in 0..n {
        let s = thin
            .sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32()))
            .unwrap();
        if s.transmitted {
            t += 1;
            assert!((s.wi + wo).length() < 1e-6);
        }
        total += s.weight.x as f64;
    }
    let frac = t as f64 / n as f64;
    println!(
        "thin smooth glass cos 0.5: transmitted {frac:.5}, 1 − F = {:.5}, furnace {:.6}",
        1.0 - f,
        total / n as f64
    );
    assert!((frac - (1.0 - f)).abs() < 5.0 * (f * (1.0 - f) / n as f64).sqrt());
    assert!((total / n as f64 - 1.0).abs() < 1e-5);
}

#[test]
fn lambertian_furnace_is_exactly_the_albedo() {
    for albedo in [Vec3::ONE, Vec3::new(0.8, 0.5, 0.1), Vec3::ZERO] {
        let b = bsdf(PbrParams::diffuse(albedo));
        assert!(b.has_non_delta() == (albedo != Vec3::ZERO) || albedo == Vec3::ZERO);
        for front in [true, false] {
            let wo = wo_at(0.3, front);
            let mut rng = Pcg32::new(17, front as u64);
            let (mut sum, mut count) = (DVec3::ZERO, 0usize);
            let n = 200_000;
            for _ in 0..n {
                let Some(s) = b.sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32())) else {
                    continue;
                };
                assert_eq!(
                    s.weight, albedo,
                    "every Lambertian sample weighs exactly the albedo"
                );
                assert!(!s.transmitted && !s.delta);
                assert!((b.eval(wo, s.wi) / s.pdf - albedo).abs().max_element() < 1e-6);
                sum += s.weight.as_dvec3();
                count += 1;
            }
            // cos θi = 0 exactly is the only rejection; at 24-bit inputs it essentially never happens.
            assert!(count as f64 > 0.9999 * n as f64);
            let mean = sum / count as f64;
            println!("Lambertian albedo {albedo}: furnace {mean}");
            assert!((mean - albedo.as_dvec3()).abs().max_element() < 1e-12);
        }
    }
    // The same surface through the general path (specular 0 but a metal-free, transmission-free
    // material that is not flagged Lambertian cannot exist): check eval directly instead.
    let b = bsdf(PbrParams {
        roughness: 0.3,
        ..PbrParams::diffuse(Vec3::new(0.5, 0.25, 1.0))
    });
    let wo = wo_at(0.4, true);
    let wi = Vec3::new(-0.3, 0.2, (1.0f32 - 0.13).sqrt());
    let e = b.eval(wo, wi);
    assert!(
        (e - Vec3::new(0.5, 0.25, 1.0) * wi.z / std::f32::consts::PI)
            .abs()
            .max_element()
            < 1e-7
    );
}

#[test]
fn light_never_leaks_through_the_geometric_surface() {
    // Shading normal tilted 40° from the geometric one: directions above the geometric surface can be
    // below the shading one.
    let ng = Vec3::Z;
    let ns = Vec3::new(0.64, 0.0, 0.77).normalize();
    let mut rng = Pcg32::new(23, 5);
    let materials = [
        plastic(TINT, 0.4),
        metal(TINT, 0.2),
        glass(TINT, 0.4, false),
        glass(TINT, 0.4, true),
        glass(TINT, 0.0, false),
        PbrParams::diffuse(TINT),
    ];
    for p in materials {
        let b = Bsdf::new(p, ns, ng, None);
        let transmits = p.transmission > 0.0;
        let mut worst: f32 = 0.0;
        for _ in 0..200_000 {
            let rand_dir = |rng: &mut Pcg32| {
                let z = 1.0 - 2.0 * rng.f32();
                let phi = 2.0 * std::f32::consts::PI * rng.f32();
                let r = (1.0 - z * z).max(0.0).sqrt();
                Vec3::new(r * phi.cos(), r * phi.sin(), z)
            };
            let wo = rand_dir(&mut rng);
            let wi = rand_dir(&mut rng);
            let same_side = (wo.dot(ng) > 0.0) == (wi.dot(ng) > 0.0);
            let e = b.eval(wo, wi);
            if !transmits && !same_side {
                assert_eq!(e, Vec3::ZERO, "{p:?}: opaque surface leaks");
                assert_eq!(b.pdf(wo, wi), 0.0);
            }
            if let Some(s) = b.sample(wo, rng.f32(), Vec2::new(rng.f32(), rng.f32())) {
                let geo_transmitted = (wo.dot(ng) > 0.0) != (s.wi.dot(ng) > 0.0);
                assert_eq!(
                    s.transmitted, geo_transmitted,
                    "{p:?}: sampled side disagrees with the geometry"
                );
                assert!(transmits || !geo_transmitted, "{p:?}: opaque sample leaked");
                if !s.delta {
                    let (e, pdf) = b.eval_pdf(wo, s.wi);
                    let rel = ((pdf - s.pdf) / s.pdf).abs().max(
                        ((e / pdf - s.weight).abs().max_element())
                            / s.weight.max_element().max(1e-6),
                    );
                    worst = worst.max(rel);
                }
            }
        }
        println!("leak guard {:?} metallic {} transmission {} thin {}: worst weight/pdf mismatch {worst:.1e}", p.roughness, p.metallic, p.transmission, p.thin_walled);
        assert!(worst < 1e-3);
    }
}
