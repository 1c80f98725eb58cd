//! The lease and upload protocol, state changes and bad input, over real HTTP on both stores.

#[path = "../common/mod.rs"]
mod common;

mod invalid_samples;
mod job_states;
mod leases;
mod uploads;

use common::*;
use pathfarm_tracer::gltf::{self, LoadOptions, NoExternalResources};
use pathfarm_tracer::{render_tile, Scene, Tile};
use pathfarm_wire::api::{JobState, Lease, WorkerState};
use pathfarm_wire::{encode_slice, Slice};
use pathfarm_worker::client::ClientError;
use reqwest::StatusCode;
use std::time::Duration;

fn load(scene: &[u8]) -> Scene {
    gltf::load(scene, &NoExternalResources, &LoadOptions::default()).unwrap()
}

fn slice_body(scene: &Scene, lease: &Lease, begin: u32, end: u32) -> Vec<u8> {
    let tile = Tile {
        x0: lease.tile.x0,
        y0: lease.tile.y0,
        width: lease.tile.width,
        height: lease.tile.height,
    };
    let acc = render_tile(scene, &lease.settings.render_settings(), tile, begin..end);
    encode_slice(&Slice {
        sample_begin: begin,
        sample_end: end,
        acc,
    })
}

fn code(e: &ClientError) -> (StatusCode, String) {
    match e {
        ClientError::Api { status, code, .. } => (*status, code.clone()),
        other => panic!("expected an API error, got {other}"),
    }
}
