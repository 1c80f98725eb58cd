//! Steps 2 and 6 of the lanes, their scalar ray queries: `trace_closest` traces each lane's
//! closest hit and loads its triangle and material; `trace_shadows` traces the shadow rays (with
//! the next rays where a path goes on) and hands on the paths that ended.

use super::{normals, Lanes, LANES};
use crate::geometry::Ray;
use crate::integrator::PathResult;
use crate::scene::Hit;

impl Lanes<'_> {
    /// Traces the closest hit of every live lane that does not have it yet, and loads the hit
    /// triangle's corners and material. `hit` is false for dead lanes and for rays that escaped.
    #[inline(always)]
    pub(super) fn trace_closest(&mut self) {
        let scene = self.scene;
        // The lanes to trace, listed first: which lanes need a ray is random, and a branch on it
        // per lane would be mispredicted about as often as not.
        let mut trace = [0u8; LANES];
        let mut n = 0;
        for i in 0..LANES {
            trace[n] = i as u8;
            n += usize::from(self.alive[i] && self.untraced[i]);
        }
        // Two lanes' rays a walk, traced together (`Bvh::closest_pair_in`); inlined: this step is
        // compiled for the test's instruction set (`builds.rs`).
        let mut pairs = trace[..n].chunks_exact(2);
        for pair in &mut pairs {
            let (i, j) = (usize::from(pair[0]), usize::from(pair[1]));
            self.rays[i] += 1;
            self.rays[j] += 1;
            let a = Ray::new(self.o.get(i), self.d.get(i));
            let b = Ray::new(self.o.get(j), self.d.get(j));
            let (alpha_a, alpha_b) = (
                self.alpha_at(i, self.depth[i]),
                self.alpha_at(j, self.depth[j]),
            );
            (self.found[i], self.found[j]) =
                scene.intersect_pair_in::<true>((&a, alpha_a), (&b, alpha_b));
        }
        for &i in pairs.remainder() {
            let i = usize::from(i);
            self.rays[i] += 1;
            let ray = Ray::new(self.o.get(i), self.d.get(i));
            let alpha_u = self.alpha_at(i, self.depth[i]);
            self.found[i] = scene.intersect_in::<true>(&ray, f32::INFINITY, alpha_u);
        }
        // Every lane loads a triangle (`miss` where there is no hit), so nothing here branches
        // but the instanced hits' move to world space.
        let instanced = !scene.instances.is_empty();
        // What a lane without a hit loads: a triangle of the scene, in its world-space mesh or in
        // its first instance (never read).
        let miss = Hit {
            t: 0.0,
            triangle: 0,
            b1: 0.0,
            b2: 0.0,
            instance: if scene.mesh.is_empty() { 0 } else { Hit::WORLD },
        };
        let mixed = self.normals == normals::MIXED;
        for i in 0..LANES {
            let found = self.found[i].filter(|_| self.alive[i]);
            self.hit[i] = found.is_some();
            let hit = found.unwrap_or(miss);
            self.t[i] = hit.t;
            let material = if instanced && hit.instance != Hit::WORLD {
                self.load_instanced(i, &hit, mixed)
            } else {
                self.load_world(i, &hit, mixed)
            };
            let m = &self.materials[material as usize];
            // A textured material's are its hit's (`shade_texels`).
            self.albedo.set(i, m.albedo);
            self.material[i] = material;
            self.emission_front.set(i, m.emission_front);
            self.emission_back.set(i, m.emission_back);
            if m.emissive_textured && self.hit[i] {
                // The texel where the ray meets it (`Material::emission` at `Scene::surface`'s
                // texture coordinates).
                let uv = scene.hit_uv(&hit);
                let material = &scene.materials[material as usize];
                let textures = &scene.textures;
                self.emission_front
                    .set(i, material.emission(textures, &uv, true));
                self.emission_back
                    .set(i, material.emission(textures, &uv, false));
            }
            self.diffuse_on[i] = m.diffuse_on;
            // The density depends on the vertex the ray left (`p` and `ng` still hold it) and on
            // where the ray meets the light: `trace_path`'s `EmissionWeight::Mis`, the normal
            // made as `shade_hit` makes it. Emitters are never instanced.
            self.light_density[i] = 0.0;
            if self.hit[i] && self.mis[i] && m.emits {
                debug_assert_eq!(hit.instance, Hit::WORLD);
                let (from, n) = (self.p.get(i), self.ng.get(i));
                let (a, b, c) = (
                    self.corner_a.get(i),
                    self.corner_b.get(i),
                    self.corner_c.get(i),
                );
                let cos_l = self.d.get(i).dot((b - a).cross(c - a).normalize()).abs();
                let choice = scene.lights.area_choice;
                let area = &scene.lights.area;
                self.light_density[i] =
                    area.pdf(from, n, hit.triangle, material, hit.t, cos_l) * choice;
            }
        }
    }

    /// Each hit's tangent, and each textured material's BSDF at its hit, as `Scene::bsdf_at`
    /// makes them (after `shade_hit` has interpolated the shading normal): the tangent orients
    /// the frames, a normal map replaces the shading normal, and the texels' parameters give the
    /// lane's Lambertian albedo and `Bsdf::has_non_delta`, or its glossy lobes (`Lanes::lobes`).
    #[inline(never)]
    pub(super) fn shade_texels(&mut self) {
        let scene = self.scene;
        for i in 0..LANES {
            let Some(hit) = self.found[i].filter(|_| self.hit[i]) else {
                continue;
            };
            let tangent = match self.tangents {
                true => scene.hit_tangent(&hit),
                false => None,
            };
            self.tangent
                .set(i, tangent.map_or(glam::Vec3::ZERO, |t| t.truncate()));
            self.tangent4[i] = tangent;
            let material = self.material[i];
            if !self.materials[material as usize].textured {
                continue;
            }
            let (ns, bsdf) = scene.textured_bsdf(material, &hit, self.ns.get(i), tangent);
            self.ns.set(i, ns);
            self.texel_lobes[i] = bsdf.glossy_lobes();
            let albedo = match bsdf.single_lobe() {
                true => bsdf.params().base_color,
                false => glam::Vec3::ZERO,
            };
            self.albedo.set(i, albedo);
            self.diffuse_on[i] = bsdf.has_non_delta();
            if self.guide.is_some() {
                // For a guided lane's sample (`Lanes::guided_bsdf`).
                self.texel_bsdf[i] = Some(bsdf);
            }
        }
    }

    /// Loads lane `i`'s hit of the world-space mesh (its barycentrics, corners and vertex
    /// normals, as `Scene::surface` reads them) and returns its material.
    #[inline(always)]
    fn load_world(&mut self, i: usize, hit: &Hit, mixed: bool) -> u32 {
        let mesh = &*self.scene.mesh;
        let tri = hit.triangle as usize;
        (self.b1[i], self.b2[i]) = (hit.b1, hit.b2);
        let [a, b, c] = mesh.positions[tri];
        self.corner_a.set(i, a);
        self.corner_b.set(i, b);
        self.corner_c.set(i, c);
        if mixed {
            self.smooth[i] = mesh.normals.is_some();
        }
        if let Some(normals) = &mesh.normals {
            let [na, nb, nc] = normals[tri];
            self.normal_a.set(i, na);
            self.normal_b.set(i, nb);
            self.normal_c.set(i, nc);
        }
        mesh.material[tri]
    }

    /// [`Lanes::load_world`] of an instanced hit: its triangle moved to world space as
    /// `Scene::surface` moves it (`Scene::instance_triangle`). (Not through one function with the
    /// world-space mesh's hits: the lanes' loop ran 1–2 % slower on scenes without instances.)
    #[inline(always)]
    fn load_instanced(&mut self, i: usize, hit: &Hit, mixed: bool) -> u32 {
        let world = self.scene.instance_triangle(hit);
        (self.b1[i], self.b2[i]) = world.bary;
        let [a, b, c] = world.corners;
        self.corner_a.set(i, a);
        self.corner_b.set(i, b);
        self.corner_c.set(i, c);
        if mixed {
            self.smooth[i] = world.normals.is_some();
        }
        if let Some([na, nb, nc]) = world.normals {
            self.normal_a.set(i, na);
            self.normal_b.set(i, nb);
            self.normal_c.set(i, nc);
        }
        world.material
    }

    /// Traces each lane's shadow ray (with its next ray, when the path goes on), adds the light
    /// it lets through, and hands on the results of the paths that ended.
    #[inline(always)]
    pub(super) fn trace_shadows(&mut self, each: &mut impl FnMut(u32, u32, u32, PathResult)) {
        let scene = self.scene;
        // Lanes listed by what they trace, without a branch per lane (as in `trace_closest`):
        // a shadow ray with the next ray, a shadow ray alone, and the paths that end.
        let (mut pairs, mut alone, mut ended) = ([0u8; LANES], [0u8; LANES], [0u8; LANES]);
        let (mut n_pairs, mut n_alone, mut n_ended) = (0, 0, 0);
        for i in 0..LANES {
            let alive = self.alive[i];
            let cont = self.go[i] && self.cont[i];
            let shadow = self.go[i] && self.shadow[i];
            pairs[n_pairs] = i as u8;
            n_pairs += usize::from(alive && shadow && cont);
            alone[n_alone] = i as u8;
            n_alone += usize::from(alive && shadow && !cont);
            ended[n_ended] = i as u8;
            n_ended += usize::from(alive && !cont);
            // A path that goes on without a shadow ray traces its next ray in `trace_closest`.
            self.untraced[i] = !shadow;
        }
        for &i in &pairs[..n_pairs] {
            let i = usize::from(i);
            self.rays[i] += 1;
            let shadow = Ray::new(self.shadow_o.get(i), self.shadow_d.get(i));
            let ray = Ray::new(self.o.get(i), self.d.get(i));
            // The next ray's bounce is one past the shadow ray's vertex (`scatter` moved it on).
            let depth = self.depth[i];
            let (alpha_u, shadow_alpha_u) = (self.alpha_at(i, depth), self.alpha_at(i, depth - 1));
            let (found, visible) = scene.intersect_and_visible_in::<true>(
                &ray,
                alpha_u,
                &shadow,
                self.shadow_t_max[i],
                shadow_alpha_u,
            );
            self.found[i] = found;
            self.add_if(i, visible);
        }
        for &i in &alone[..n_alone] {
            let i = usize::from(i);
            let shadow = Ray::new(self.shadow_o.get(i), self.shadow_d.get(i));
            let alpha_u = self.alpha_at(i, self.depth[i]);
            let visible = scene.visible_in::<true>(&shadow, self.shadow_t_max[i], alpha_u);
            self.add_if(i, visible);
        }
        for &i in &ended[..n_ended] {
            let i = usize::from(i);
            self.alive[i] = false;
            let result = PathResult {
                radiance: self.l.get(i),
                rays: self.rays[i],
                vertices: self.vertices[i],
            };
            each(self.x[i], self.y[i], self.index[i], result);
        }
    }

    /// Adds lane `i`'s light sample to its radiance if its shadow ray was clear (a select, not a
    /// branch: visibility is random).
    #[inline(always)]
    fn add_if(&mut self, i: usize, visible: bool) {
        let l = self.l.get(i);
        let lit = l + self.shadow_value.get(i);
        self.l.set(i, if visible { lit } else { l });
    }
}
