//! JSON control messages of the REST API (`openapi.yaml`), shared by the server, the worker and the
//! command-line client so that all three agree on one contract.

use serde::{Deserialize, Serialize};

mod by_name;
mod errors;
mod integer;
mod jobs;
mod settings;
mod tasks;
mod workers;

pub use errors::{ErrorBody, ErrorDetail};
pub use jobs::{
    Convergence, ConvergencePoint, FrameProgress, JobCreated, JobList, JobPatch, JobState, JobView,
    PreviewView, SCALE_MAX_HEADER, SCALE_MIN_HEADER,
};
pub use settings::{EnvironmentSettings, FrameOrder, JobSettings};
pub use tasks::{Lease, Release, SliceAck, TileProgress, TileRect};
pub use workers::{
    Heartbeat, HeartbeatReply, WorkerList, WorkerRegistered, WorkerRegistration, WorkerState,
    WorkerView,
};

/// Path prefix of every versioned endpoint.
pub const API_PREFIX: &str = "/api/v1";
/// Media type of a binary slice body (see [`crate::slice`]): the generic binary type, the one
/// client generators can send (the body's magic and version say what it is).
pub const SLICE_CONTENT_TYPE: &str = "application/octet-stream";
/// The slice body's own media type, which workers sent before [`SLICE_CONTENT_TYPE`]: still
/// accepted.
pub const SLICE_CONTENT_TYPE_LEGACY: &str = "application/x-pathfarm-slice";
/// Header that carries a task's lease token on slice uploads.
pub const LEASE_TOKEN_HEADER: &str = "pathfarm-lease-token";
/// Header that carries a worker's own credential (from its registration) on every call it makes
/// for itself: lease, heartbeat, sign-off, slice upload, release, scene download.
pub const WORKER_CREDENTIAL_HEADER: &str = "pathfarm-worker-credential";

/// `GET /healthz`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Health {
    pub status: String,
    pub version: String,
    pub store: String,
}

#[cfg(test)]
mod tests {
    use super::*;
    use pathfarm_tracer::{DirectStrategy, RussianRoulette, SamplerKind};

    #[test]
    fn settings_round_trip_by_name() {
        let mut s = JobSettings::new(64, 32, 16);
        s.rr = RussianRoulette::Fixed(0.5);
        s.direct = DirectStrategy::Light;
        s.sampler = SamplerKind::Independent;
        let json = serde_json::to_string(&s).unwrap();
        assert!(json.contains("\"direct\":\"light\""), "{json}");
        assert!(json.contains("\"rr\":\"0.5\""), "{json}");
        let back: JobSettings = serde_json::from_str(&json).unwrap();
        assert_eq!(back, s);
    }

    /// The environment's floats reach the worker as JSON text; a render is the same bits as a local
    /// one only if every finite f32 comes back exactly (serde_json writes the shortest digits that
    /// round to the f32, and the f64 it reads them into rounds back to the same f32).
    #[test]
    fn environment_floats_survive_json_bit_for_bit() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            f32::from_bits((state >> 32) as u32)
        };
        let mut checked = 0;
        while checked < 200_000 {
            let v = [next(), next(), next(), next(), next()];
            if v.iter().any(|x| !x.is_finite()) {
                continue;
            }
            let mut s = JobSettings::new(8, 8, 1);
            s.environment = Some(EnvironmentSettings {
                radiance: Some([v[0], v[1], v[2]]),
                image: None,
                strength: v[3],
                rotation_degrees: v[4],
            });
            let back: JobSettings = serde_json::from_str(&serde_json::to_string(&s).unwrap())
                .unwrap_or_else(|e| panic!("{v:?}: {e}"));
            let env = back.environment.expect("environment kept");
            let got = [
                env.radiance.expect("radiance kept"),
                [env.strength, env.rotation_degrees, 0.0],
            ];
            let bits = |x: f32| x.to_bits();
            assert_eq!(got[0].map(bits), [v[0], v[1], v[2]].map(bits), "{v:?}");
            assert_eq!([got[1][0], got[1][1]].map(bits), [v[3], v[4]].map(bits));
            checked += 1;
        }
    }

    #[test]
    fn settings_defaults_and_errors() {
        let s: JobSettings = serde_json::from_str(r#"{"width":8,"height":4,"spp":2}"#).unwrap();
        assert_eq!(s, JobSettings::new(8, 4, 2));
        let e = serde_json::from_str::<JobSettings>(
            r#"{"width":8,"height":4,"spp":2,"direct":"magic"}"#,
        )
        .unwrap_err();
        assert!(
            e.to_string().contains("unknown direct-lighting strategy"),
            "{e}"
        );
        let e = serde_json::from_str::<JobSettings>(r#"{"width":8,"height":4,"spp":2,"sppp":3}"#)
            .unwrap_err();
        assert!(e.to_string().contains("unknown field"), "{e}");
    }

    #[test]
    fn integers_may_be_written_as_integral_numbers() {
        // JSON Schema's `integer` is any number with no fractional part: 99999.0 is 99999.
        let s: JobSettings = serde_json::from_str(
            r#"{"width":8.0,"height":4,"spp":2e0,"seed":7.0,"tile_size":16.0,"max_depth":3.0,"priority":-99999.0}"#,
        )
        .unwrap();
        assert_eq!((s.width, s.height, s.spp, s.seed), (8, 4, 2, 7));
        assert_eq!(
            (s.tile_size, s.max_depth, s.priority),
            (16, Some(3), -99999)
        );
        let none: JobSettings =
            serde_json::from_str(r#"{"width":8,"height":4,"spp":2,"max_depth":null}"#).unwrap();
        assert_eq!(none.max_depth, None);
        let p: JobPatch = serde_json::from_str(r#"{"priority":99999.0}"#).unwrap();
        assert_eq!(p.priority, 99999);
        let r: WorkerRegistration =
            serde_json::from_str(r#"{"name":"w","threads":4.0,"version":"v","host":"h"}"#).unwrap();
        assert_eq!(r.threads, 4);
        let h: Heartbeat = serde_json::from_str(r#"{"task_id":12.0}"#).unwrap();
        assert_eq!(h.task_id, Some(12));

        // Fractions, out-of-range values and inexact huge floats are still errors.
        for bad in [
            r#"{"width":8.5,"height":4,"spp":2}"#,
            r#"{"width":-8,"height":4,"spp":2}"#,
            r#"{"width":4294967296,"height":4,"spp":2}"#,
            r#"{"width":8,"height":4,"spp":2,"seed":1e300}"#,
            r#"{"width":8,"height":4,"spp":2,"priority":3000000000.0}"#,
            r#"{"width":8,"height":4,"spp":"2"}"#,
        ] {
            let e = serde_json::from_str::<JobSettings>(bad).unwrap_err();
            assert!(e.to_string().contains("an integer in range"), "{bad}: {e}");
        }
    }
}
