//! Frame jobs (animations) on the farm, on both stores: every frame's image is bit-identical to a
//! local render of the scene at that frame (`pathfarm render --frame N --fps F`), whatever the
//! workers, tiles and slices; the lease order is interleaved (every frame's first pass before any
//! second pass) or sequential (frame after frame); bad specifications are 4xx with JSON.

#[path = "../common/mod.rs"]
mod common;

mod bad_settings;
mod downloads;
mod images;
mod noise_target;
mod scheduling;

use axum::http::StatusCode;
use common::*;
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources, SceneSource};
use pathfarm_tracer::{render_image, Accumulation};
use pathfarm_wire::api::{ErrorBody, FrameOrder, JobSettings, JobState, WorkerRegistration};
use std::path::PathBuf;
use std::time::Duration;

/// Blender's animated export: a cube that slides and turns, a camera on an arc, a lamp that
/// rises, a bending skinned bar, a bulging morphed sphere (frames 1–48 at 24 fps).
fn animated() -> Vec<u8> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes/suite/animated.glb");
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `pathfarm render --frame frame --fps fps` of the job's settings, as EXR bytes.
fn local_frame(scene: &[u8], s: &JobSettings, frame: i64) -> Vec<u8> {
    exr(&local_accumulation(scene, s, frame))
}

/// `pathfarm render --frame frame --fps fps` of the job's settings.
fn local_accumulation(scene: &[u8], s: &JobSettings, frame: i64) -> Accumulation {
    let source = SceneSource::load(scene, &NoExternalResources, &LoadOptions::default()).unwrap();
    let time = gltf::frame_time(frame, s.frames_per_second());
    let scene = source.into_scene_at(time).unwrap().with_environment(None);
    render_image(&scene, &s.render_settings(), 32, 0..s.spp, &|_| {})
}

fn frame_settings(frames: &str, order: Option<FrameOrder>, tile: u32) -> JobSettings {
    let mut s = settings(24, 16, 3, tile);
    s.frames = Some(frames.into());
    s.fps = Some(24.0);
    s.frame_order = order;
    s
}

/// A slice of `lease`'s whole sample range with the same valid value in every sample (what it
/// shows does not matter here, only that it is merged).
fn flat_slice(lease: &pathfarm_wire::api::Lease) -> Vec<u8> {
    flat_slice_of(lease, lease.sample_begin, lease.sample_end)
}

/// [`flat_slice`] of samples `begin..end` of `lease`'s range.
fn flat_slice_of(lease: &pathfarm_wire::api::Lease, begin: u32, end: u32) -> Vec<u8> {
    let t = &lease.tile;
    let mut acc = pathfarm_tracer::Accumulation::new(t.x0, t.y0, t.width, t.height);
    for p in &mut acc.pixels {
        for _ in begin..end {
            p.add_sample(glam::Vec3::splat(0.5));
        }
    }
    pathfarm_wire::encode_slice(&pathfarm_wire::Slice {
        sample_begin: begin,
        sample_end: end,
        acc,
    })
}
