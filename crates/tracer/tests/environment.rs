//! The environment light: its sampling distribution against its density (χ²), its images decoded
//! from both formats, and renders under it against exact answers for every direct-lighting
//! strategy — a Lambertian plane under an environment reflects ρ/π ∫ L(ω) max(0, ω·n) dω, which
//! for a uniform environment is ρ L (the furnace), and for an image is a sum over its texels
//! computed here independently of the tracer's mapping code.

mod common;

use common::*;
use glam::{Affine3A, Quat, Vec3};
use pathfarm_tracer::camera::{Camera, Perspective, Projection};
use pathfarm_tracer::geometry::Mesh;
use pathfarm_tracer::light::Environment;
use pathfarm_tracer::scene::SceneParts;
use pathfarm_tracer::stats::chi_square_test;
use pathfarm_tracer::{render_image, DirectStrategy, RenderSettings, SamplerKind, Scene};
use std::f64::consts::PI;
use std::io::Cursor;

/// A Radiance `.hdr` file of `texels` (row by row from the top), as a user would bring.
fn hdr_bytes(width: usize, height: usize, texels: &[Vec3]) -> Vec<u8> {
    let pixels: Vec<image::Rgb<f32>> = texels.iter().map(|t| image::Rgb(t.to_array())).collect();
    let mut out = Vec::new();
    image::codecs::hdr::HdrEncoder::new(&mut out)
        .encode(&pixels, width, height)
        .expect("encodes");
    out
}

/// An OpenEXR file of `texels` (float32 RGB).
fn exr_bytes(width: usize, height: usize, texels: &[Vec3]) -> Vec<u8> {
    use exr::prelude::*;
    let image = Image::from_channels(
        (width, height),
        SpecificChannels::rgb(|p: Vec2<usize>| {
            let t = texels[p.y() * width + p.x()];
            (t.x, t.y, t.z)
        }),
    );
    let mut out = Cursor::new(Vec::new());
    image.write().to_buffered(&mut out).expect("encodes");
    out.into_inner()
}

/// Texel values exactly representable in RGBE (8-bit mantissas sharing an exponent), with one
/// texel a thousand times brighter than the rest: a small sun.
fn sky(width: usize, height: usize) -> Vec<Vec3> {
    let mut rng = Pcg32::seeded(11);
    let mut texels: Vec<Vec3> = (0..width * height)
        .map(|_| {
            let q = |x: f32| (x * 16.0).floor() / 16.0;
            Vec3::new(q(rng.f32()), q(rng.f32()), q(rng.f32())) + Vec3::splat(0.0625)
        })
        .collect();
    texels[(height / 2 - 1) * width + width / 4] = Vec3::new(1024.0, 768.0, 512.0);
    texels
}

/// The direction of image point (u, v) (v = 0 at the top) in glTF axes, as Blender maps an
/// equirectangular image, turned by `rotation` degrees (a Mapping node's Z rotation). Written
/// here in f64 from Blender's formulas, not with the tracer's code.
fn blender_direction(u: f64, v: f64, rotation: f64) -> glam::DVec3 {
    let phi = 2.0 * PI * (0.5 - u);
    let e = PI * (0.5 - v);
    let (rx, ry, z) = (e.cos() * phi.cos(), e.cos() * phi.sin(), e.sin());
    let (s, c) = rotation.to_radians().sin_cos();
    let (bx, by) = (rx * c + ry * s, -rx * s + ry * c);
    glam::DVec3::new(bx, z, -by)
}

/// ∫ L(ω) max(0, ω·n) dω over an image environment, by the midpoint rule on `sub`² points per
/// texel (the integrand is smooth inside a texel).
fn cosine_integral(
    width: usize,
    height: usize,
    texels: &[Vec3],
    rotation: f64,
    n: glam::DVec3,
) -> f64 {
    let sub = 16;
    let (du, dv) = (1.0 / (width * sub) as f64, 1.0 / (height * sub) as f64);
    let mut total = 0.0;
    for y in 0..height {
        for x in 0..width {
            let l = texels[y * width + x];
            let lum = 0.2126 * l.x as f64 + 0.7152 * l.y as f64 + 0.0722 * l.z as f64;
            let mut acc = 0.0;
            for j in 0..sub {
                let v = (y * sub + j) as f64 * dv + 0.5 * dv;
                let cos_e = (PI * (0.5 - v)).cos();
                for i in 0..sub {
                    let u = (x * sub + i) as f64 * du + 0.5 * du;
                    let w = blender_direction(u, v, rotation);
                    acc += w.dot(n).max(0.0) * cos_e;
                }
            }
            total += lum * acc * du * dv * 2.0 * PI * PI;
        }
    }
    total
}

#[test]
fn both_file_formats_decode_to_the_same_environment() {
    let (w, h) = (16, 8);
    let texels = sky(w, h);
    let from_hdr = Environment::from_image(&hdr_bytes(w, h, &texels), 2.0, 0.0).unwrap();
    let from_exr = Environment::from_image(&exr_bytes(w, h, &texels), 2.0, 0.0).unwrap();
    let mut rng = Pcg32::seeded(3);
    for _ in 0..2000 {
        let d = pathfarm_tracer::sampling::sample_uniform_sphere(rng.vec2());
        assert_eq!(from_hdr.radiance(d), from_exr.radiance(d), "{d}");
        assert_eq!(from_hdr.pdf(d), from_exr.pdf(d));
    }
    // Strength scales the radiance; the centre of the image is Blender's +x.
    let centre = texels[(h / 2) * w + w / 2] * 2.0;
    assert_eq!(
        from_exr.radiance(Vec3::new(1.0, -0.01, 0.01).normalize()),
        centre
    );
}

#[test]
fn oversized_and_broken_images_are_refused_with_reasons() {
    let e = Environment::from_image(&hdr_bytes(4, 2, &[Vec3::ONE; 8])[..30], 1.0, 0.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("Radiance"), "{e}");
    // A header claiming 2^30 texels is refused before anything is decoded.
    let mut lying = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 32768 +X 32768\n".to_vec();
    lying.extend_from_slice(&[0; 16]);
    let e = Environment::from_image(&lying, 1.0, 0.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("at most"), "{e}");
    let mut negative = sky(4, 2);
    negative[5] = Vec3::new(0.0, -1.0, 0.0);
    let e = Environment::from_image(&exr_bytes(4, 2, &negative), 1.0, 0.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("texel (1, 1)"), "{e}");
}

/// Where direction `d` (glTF axes) looks up an image turned by `rotation` degrees: Blender's
/// formulas in f64, the inverse of [`blender_direction`].
fn blender_uv(d: Vec3, rotation: f64) -> (f64, f64) {
    let d = d.as_dvec3().normalize();
    let (bx, by, bz) = (d.x, -d.z, d.y);
    let (s, c) = rotation.to_radians().sin_cos();
    let (rx, ry) = (bx * c - by * s, bx * s + by * c);
    (
        0.5 - ry.atan2(rx) / (2.0 * PI),
        0.5 - bz.clamp(-1.0, 1.0).asin() / PI,
    )
}

/// The sampled directions follow `Environment::pdf` (χ², 1M samples), binned on a grid aligned
/// with the image's texels (the rotation is a whole number of texel columns), where the density is
/// constant in each bin and the expected counts are exact; a density without the equirectangular
/// map's cos(elevation) Jacobian is rejected by the same test.
#[test]
fn environment_sampling_matches_its_pdf() {
    let (w, h) = (16, 8);
    let rotation = 45.0; // two texel columns
    let env = Environment::from_image(&exr_bytes(w, h, &sky(w, h)), 1.0, rotation as f32).unwrap();
    let (bw, bh) = (2 * w, 2 * h);
    let n = 1_000_000;
    let mut observed = vec![0.0f64; bw * bh];
    let mut rng = Pcg32::seeded(21);
    let mut estimate = 0.0f64;
    // A sample on a cell's edge may look up the neighbouring cell by a rounding: rare.
    let mut disagree = 0;
    for _ in 0..n {
        let s = env.sample(rng.vec2()).expect("a sample");
        assert!((s.wi.length() - 1.0).abs() < 1e-5);
        if (s.pdf - env.pdf(s.wi)).abs() > 1e-3 * s.pdf || s.radiance != env.radiance(s.wi) {
            disagree += 1;
        }
        let (u, v) = blender_uv(s.wi, rotation);
        let (i, j) = (
            ((u * bw as f64) as usize).min(bw - 1),
            ((v * bh as f64) as usize).min(bh - 1),
        );
        observed[j * bw + i] += 1.0;
        estimate += (s.radiance.y / s.pdf) as f64;
    }
    assert!(
        disagree < n / 10_000,
        "{disagree} samples disagree with pdf()"
    );
    // ∫ pdf dω over a bin = Σ pdf(ω) · 2π² cos e · ΔuΔv at sub-bin midpoints (exact where the
    // density is constant in the bin: pdf · cos e is then constant too).
    let integrate = |pdf: &dyn Fn(Vec3) -> f64| -> Vec<f64> {
        let sub = 4;
        let (du, dv) = (1.0 / (bw * sub) as f64, 1.0 / (bh * sub) as f64);
        let mut out = vec![0.0; bw * bh];
        for (k, e) in out.iter_mut().enumerate() {
            let (i, j) = (k % bw, k / bw);
            for a in 0..sub {
                for b in 0..sub {
                    let u = (i * sub + a) as f64 * du + 0.5 * du;
                    let v = (j * sub + b) as f64 * dv + 0.5 * dv;
                    let d = blender_direction(u, v, rotation).as_vec3();
                    *e += pdf(d) * 2.0 * PI * PI * (PI * (0.5 - v)).cos() * du * dv * n as f64;
                }
            }
        }
        out
    };
    let expected = integrate(&|d| env.pdf(d) as f64);
    let chi = chi_square_test(&observed, &expected, 5.0);
    eprintln!("environment sampling: p = {:.3e}", chi.p_value);
    assert!(chi.p_value > 1e-4, "{chi:?}");
    // The importance-sampled estimate of ∫ L_green dω is unbiased:
    // ∫ L dω = Σ L · (2π/w) · ∫ cos e de over each texel's rows of elevation e.
    let exact: f64 = sky(w, h)
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let row = (i / w) as f64;
            let (e0, e1) = (
                PI * (0.5 - row / h as f64),
                PI * (0.5 - (row + 1.0) / h as f64),
            );
            l.y as f64 * (2.0 * PI / w as f64) * (e0.sin() - e1.sin())
        })
        .sum();
    let mean = estimate / n as f64;
    assert!((mean - exact).abs() < 0.01 * exact, "{mean} vs {exact}");

    // Without the Jacobian the law is wrong, and the test says so.
    let wrong = integrate(&|d| {
        let cos_e = (d.x * d.x + d.z * d.z).sqrt() as f64;
        env.pdf(d) as f64 * cos_e * 4.0 / PI
    });
    let p = chi_square_test(&observed, &wrong, 5.0).p_value;
    assert!(p < 1e-6, "a wrong density passed: p = {p}");
}

/// A one-sided Lambertian square of half-size 3 facing `normal`, filling the view of a camera one
/// unit in front of it: every pixel sees the plane, and every point of it the whole hemisphere.
fn plane_facing(normal: Vec3, rho: f32, extra: Vec<[Vec3; 3]>, extra_le: f32) -> Scene {
    plane_of_size(normal, 3.0, rho, extra, extra_le)
}

/// [`plane_facing`] with half-size `s`.
fn plane_of_size(normal: Vec3, s: f32, rho: f32, extra: Vec<[Vec3; 3]>, extra_le: f32) -> Scene {
    let rotation = Quat::from_rotation_arc(Vec3::Z, normal);
    let c = |x: f32, y: f32| rotation * Vec3::new(x, y, 0.0);
    let mut mesh = Mesh::default();
    mesh.positions.push([c(-s, -s), c(s, -s), c(s, s)]);
    mesh.positions.push([c(-s, -s), c(s, s), c(-s, s)]);
    mesh.material = vec![0, 0];
    for t in extra {
        mesh.positions.push(t);
        mesh.material.push(1);
    }
    let camera = Camera::new(
        Projection::Perspective(Perspective::new(60f32.to_radians())),
        Affine3A::from_rotation_translation(rotation, normal),
    );
    let mut light = lambert(0.0, extra_le);
    light.double_sided = false;
    Scene::build(SceneParts {
        mesh,
        materials: vec![lambert(rho, 0.0), light],
        camera: Some(camera),
        ..SceneParts::default()
    })
    .expect("scene builds")
}

fn render_mean(
    scene: &Scene,
    direct: DirectStrategy,
    sampler: SamplerKind,
    spp: u32,
) -> (f64, f64) {
    let settings = RenderSettings {
        direct,
        sampler,
        seed: 5,
        ..RenderSettings::new(24, 24)
    };
    let acc = render_image(scene, &settings, 8, 0..spp, &|_| {});
    assert_eq!(acc.invalid_count, 0);
    image_mean_and_stderr(&acc)
}

fn assert_close(what: &str, (mean, se): (f64, f64), exact: f64) {
    let z = (mean - exact) / se.max(1e-12);
    eprintln!("{what}: {mean:.5} ± {se:.5}, exact {exact:.5}, z = {z:+.2}");
    assert!(z.abs() < 3.5, "{what}: {mean} vs {exact} (z = {z:.2})");
    assert!(se < 0.02 * exact, "{what}: test too weak, se {se}");
}

/// The furnace: under a uniform environment of radiance 1 a Lambertian plane of albedo ρ reflects
/// exactly ρ, whichever strategy estimates it.
#[test]
fn a_plane_under_a_uniform_environment_reflects_its_albedo() {
    let rho = 0.8f32;
    for (env, name) in [
        (Environment::uniform(Vec3::ONE).unwrap(), "uniform"),
        (
            Environment::from_image(&exr_bytes(8, 4, &[Vec3::ONE; 32]), 1.0, 10.0).unwrap(),
            "constant image",
        ),
    ] {
        let scene = plane_facing(Vec3::new(0.3, 1.0, -0.2).normalize(), rho, vec![], 0.0)
            .with_environment(Some(env));
        for direct in DirectStrategy::ALL {
            for sampler in [SamplerKind::Sobol, SamplerKind::Independent] {
                let what = format!("{name} {direct} {sampler}");
                assert_close(&what, render_mean(&scene, direct, sampler, 16), rho as f64);
            }
        }
    }
}

/// A ground plane far larger than the camera's distance to it (a Blender plane scaled to a
/// horizon): its vertices are thousands of times farther from the hit point than the camera, so
/// the hit point interpolated from them carries an error that many times larger than one scaled to
/// the hit point alone. Spawned rays must still leave the surface: with BSDF sampling under a
/// uniform environment every sample is exactly ρ, and a ray that re-hits its own plane makes it ρ².
#[test]
fn rays_leave_a_huge_plane_near_the_camera() {
    let rho = 0.8f32;
    let env = Environment::uniform(Vec3::ONE).unwrap();
    for half_size in [1e3f32, 1e4, 1e5] {
        for normal in [Vec3::Y, Vec3::new(0.3, 1.0, -0.2).normalize()] {
            let scene = plane_of_size(normal, half_size, rho, vec![], 0.0)
                .with_environment(Some(env.clone()));
            let settings = RenderSettings {
                direct: DirectStrategy::Bsdf,
                seed: 3,
                ..RenderSettings::new(24, 24)
            };
            let acc = render_image(&scene, &settings, 8, 0..64, &|_| {});
            let short = acc
                .pixels
                .iter()
                .filter(|p| (p.mean()[1] - rho as f64).abs() > 1e-5)
                .count();
            assert_eq!(
                short, 0,
                "half-size {half_size}, normal {normal}: {short} of 576 pixels lost light"
            );
        }
    }
}

/// Under an image with a small sun, a plane facing sideways (so the image's azimuth and the
/// rotation matter) reflects ρ/π ∫ L max(0, ω·n) dω, computed from the texels here.
#[test]
fn a_plane_under_an_image_reflects_the_cosine_weighted_integral() {
    let (w, h) = (16, 8);
    let texels = sky(w, h);
    let rho = 0.5f32;
    for (normal, rotation) in [(Vec3::Z, 0.0f32), (Vec3::X, 90.0), (Vec3::Y, -40.0)] {
        let env = Environment::from_image(&hdr_bytes(w, h, &texels), 1.0, rotation).unwrap();
        let exact =
            rho as f64 / PI * cosine_integral(w, h, &texels, rotation as f64, normal.as_dvec3());
        let scene = plane_facing(normal, rho, vec![], 0.0).with_environment(Some(env));
        // BSDF sampling alone rarely finds the sun: more samples for it and the direction
        // strategies, whose variance it dominates.
        for (direct, spp) in [
            (DirectStrategy::Mis, 64),
            (DirectStrategy::Light, 1024),
            (DirectStrategy::Bsdf, 1024),
            (DirectStrategy::Cosine, 1024),
        ] {
            let what = format!("normal {normal} rotation {rotation} {direct}");
            assert_close(
                &what,
                render_mean(&scene, direct, SamplerKind::Sobol, spp),
                exact,
            );
        }
    }
}

/// With emissive triangles as well, the light sample is shared between the two families: the
/// image is the sum of the environment's (the emitter black) and the emitter's (no environment).
#[test]
fn area_lights_and_the_environment_add_up() {
    let (w, h) = (16, 8);
    let texels = sky(w, h);
    // An emitting triangle above the plane, facing it, outside the camera's view.
    let tri = vec![[
        Vec3::new(2.0, -1.0, 2.0),
        Vec3::new(2.0, 1.0, 2.0),
        Vec3::new(3.0, 0.0, 1.5),
    ]];
    // An image, light-sampled beside the emitter, and one colour, which only the paths' own
    // BSDF samples find (`Lights::set_environment`): under the light strategy the emitter's
    // light comes from the light sample alone and the colour's from the path's rays alone.
    let image = || Environment::from_image(&hdr_bytes(w, h, &texels), 0.5, 0.0).unwrap();
    let colour = || Environment::uniform(Vec3::new(0.3, 0.4, 0.5)).unwrap();
    for (name, env) in [
        ("image", &image as &dyn Fn() -> Environment),
        ("colour", &colour),
    ] {
        let both = plane_facing(Vec3::Z, 0.5, tri.clone(), 4.0).with_environment(Some(env()));
        let env_only = plane_facing(Vec3::Z, 0.5, tri.clone(), 0.0).with_environment(Some(env()));
        let light_only = plane_facing(Vec3::Z, 0.5, tri.clone(), 4.0);
        let sampled = both.lights.environment_choice > 0.0;
        assert_eq!(sampled, name == "image", "{name}: light-sampled");
        assert!(both.lights.area_choice > 0.0);
        for direct in [
            DirectStrategy::Mis,
            DirectStrategy::Light,
            DirectStrategy::Cosine,
        ] {
            let spp = if direct == DirectStrategy::Cosine {
                512
            } else {
                128
            };
            let (a, sa) = render_mean(&both, direct, SamplerKind::Independent, spp);
            let (b, sb) = render_mean(&env_only, direct, SamplerKind::Sobol, spp);
            let (c, sc) = render_mean(&light_only, direct, SamplerKind::Sobol, spp);
            let z = (a - b - c) / (sa * sa + sb * sb + sc * sc).sqrt();
            eprintln!(
                "{name} {direct}: both {a:.5} ± {sa:.5}, env {b:.5} + light {c:.5}, z = {z:+.2}"
            );
            assert!(
                z.abs() < 3.5,
                "{name} {direct}: {a} ≠ {b} + {c} (z = {z:.2})"
            );
            assert!(c > 10.0 * sc, "the emitter must light the plane visibly");
            assert!(
                b > 10.0 * sb,
                "the environment must light the plane visibly"
            );
        }
    }
}

/// Scenes without an environment keep the wavefront integrator; one with an environment renders
/// the same bits whichever integrator would otherwise have rendered it (it falls back to the
/// scalar path), and `with_environment(None)` gives the original scene's bits back.
#[test]
fn removing_the_environment_restores_the_original_bits() {
    let scene = furnace_sphere(0.5, 1.0);
    let settings = RenderSettings::new(16, 16);
    let before = render_image(&scene, &settings, 8, 0..4, &|_| {});
    let lit = scene.with_environment(Some(Environment::uniform(Vec3::ONE).unwrap()));
    // Inside a closed sphere no ray escapes: same image, though other code rendered it.
    let inside = render_image(&lit, &settings, 8, 0..4, &|_| {});
    let restored = lit.with_environment(None);
    let after = render_image(&restored, &settings, 8, 0..4, &|_| {});
    let bits = |a: &pathfarm_tracer::Accumulation| {
        a.pixels
            .iter()
            .map(|p| format!("{p:?}"))
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&before), bits(&after));
    // The light sample goes to the (never visible) environment some of the time: different
    // samples, same expectation.
    let (m0, s0) = image_mean_and_stderr(&before);
    let (m1, s1) = image_mean_and_stderr(&inside);
    assert!(
        (m0 - m1).abs() < 4.0 * (s0 * s0 + s1 * s1).sqrt(),
        "{m0} vs {m1}"
    );
}
