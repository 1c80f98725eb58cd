//! The caustic guide in the lanes (`lanes/guided.rs`): where a scene has a guide, the lanes in
//! its cells draw their continuation from its mixture and weigh their light samples with the
//! mixture's density, as `trace_path` does, bit for bit.

use super::{assert_same_bits, parts, pixels_that_differ, scene, settings, sky};
use crate::settings::RussianRoulette;

/// The shipped caustics box (Lambertian walls, a glass and a mirror sphere under an area
/// light): with and without its guide the images differ, and with it the lanes render every
/// sample as the scalar integrator does: as it is, with some walls glossy (the glossy lanes' BSDF
/// under the mixture) and under a sky (the environment's light samples weighed by it).
#[test]
fn guided_lanes_draw_the_mixture_as_the_scalar_integrator_draws_it() {
    let caustics = scene(parts("caustics"));
    let guide = caustics
        .caustic_guide()
        .expect("the caustics box has a guide");
    assert!(guide.cells() > 100, "{} cells", guide.cells());
    let plain = scene(parts("caustics")).without_caustic_guide();
    let s = settings(1, RussianRoulette::Auto, None);
    assert!(pixels_that_differ(&caustics, &plain, &s) > 100);
    for (seed, rr, depth) in [
        (51, RussianRoulette::Auto, None),
        (52, RussianRoulette::Max, None),
        (53, RussianRoulette::Off, Some(5)),
    ] {
        assert_same_bits(&caustics, &settings(seed, rr, depth), 0..8);
    }

    let mut p = parts("caustics");
    // Every other diffuse material made glossy: Lambertian lanes (whose BSDF branch the vector
    // loop reweighs) beside glossy ones (sampled lane by lane) in the same steps.
    let (mut diffuse, mut glossy) = (0, 0);
    for m in p.materials.iter_mut() {
        if m.emissive == glam::Vec3::ZERO && m.transmission == 0.0 && m.metallic == 0.0 {
            diffuse += 1;
            if diffuse % 2 == 1 {
                (m.roughness, m.specular) = (0.4, 1.0);
                glossy += 1;
            }
        }
    }
    assert!(
        glossy >= 2 && diffuse > glossy,
        "{glossy} of {diffuse} made glossy"
    );
    let glossy_walls = scene(p);
    assert!(glossy_walls.caustic_guide().is_some());
    assert!(pixels_that_differ(&caustics, &glossy_walls, &s) > 100);
    assert_same_bits(
        &glossy_walls,
        &settings(54, RussianRoulette::Auto, None),
        0..8,
    );

    let under_sky = scene(parts("caustics")).with_environment(Some(sky()));
    assert!(under_sky.caustic_guide().is_some());
    assert_same_bits(
        &under_sky,
        &settings(55, RussianRoulette::Auto, Some(6)),
        0..8,
    );
}
