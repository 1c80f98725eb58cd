//! Environment lighting as part of a job, and the scene loader's warnings kept with it: a real
//! server on a real port and a real worker over HTTP, on both stores. A uniform environment, an
//! uploaded image (Radiance `.hdr` and OpenEXR) and an image named by the hash the server stored it
//! under all render to the bits of a local render of the scene lit by the environment that
//! `pathfarm render` builds from the same settings; broken, unknown and contradictory environments
//! are 422s with a JSON error body and create nothing.

mod common;

use axum::http::StatusCode;
use common::*;
use glam::Vec3;
use pathfarm_wire::api::{EnvironmentSettings, ErrorBody, JobList, JobSettings, JobView};
use sha2::{Digest, Sha256};
use std::io::Cursor;
use std::time::Duration;

/// A small equirectangular sky as a Radiance `.hdr` file: a gradient with a bright spot.
fn hdr_sky(width: usize, height: usize) -> Vec<u8> {
    let pixels: Vec<image::Rgb<f32>> = (0..width * height)
        .map(|i| {
            let (x, y) = (i % width, i / width);
            let mut c = [
                0.25 + x as f32 / width as f32,
                0.5,
                1.0 - 0.5 * y as f32 / height as f32,
            ];
            if (x, y) == (width / 4, height / 4) {
                c = [40.0, 30.0, 20.0];
            }
            image::Rgb(c)
        })
        .collect();
    let mut out = Vec::new();
    image::codecs::hdr::HdrEncoder::new(&mut out)
        .encode(&pixels, width, height)
        .expect("encodes");
    out
}

/// The same kind of sky as an OpenEXR file (float32 RGB).
fn exr_sky(width: usize, height: usize) -> Vec<u8> {
    use exr::prelude::*;
    let image = Image::from_channels(
        (width, height),
        SpecificChannels::rgb(|p: Vec2<usize>| {
            (
                0.1 + p.x() as f32 / width as f32,
                0.3 + p.y() as f32 / height as f32,
                0.7f32,
            )
        }),
    );
    let mut out = Cursor::new(Vec::new());
    image.write().to_buffered(&mut out).expect("encodes");
    out.into_inner()
}

fn sha256(bytes: &[u8]) -> String {
    hex::encode(Sha256::digest(bytes))
}

/// What `pathfarm render --environment …` computes for the job: the scene lit by the environment
/// built by the one function the CLI and the worker share.
fn local_render_lit(scene: &[u8], s: &JobSettings, image: Option<&[u8]>) -> Vec<u8> {
    let env = s
        .environment
        .as_ref()
        .map(|e| e.build(image).expect("a valid environment"));
    exr(&local_render_with(scene, s, env))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn environment_jobs_are_bit_identical_to_a_local_render() {
    let scene = cornell();
    let hdr = hdr_sky(32, 16);
    let exr_image = exr_sky(16, 8);
    for (store, url) in stores("environment").await {
        let server = TestServer::start(config(&url)).await;
        let client = server.client(None);
        let worker = TestWorker::spawn(&server.url, None, Some(2));
        let unlit = exr(&local_render(&scene, &settings(24, 20, 4, 16)));

        // A uniform radiance, given in the settings.
        let mut uniform = settings(24, 20, 4, 16);
        uniform.environment = Some(EnvironmentSettings {
            radiance: Some([0.3, 0.5, 0.8]),
            strength: 1.7,
            ..EnvironmentSettings::default()
        });
        // Images, uploaded as the `environment` part with strength and rotation in the settings.
        let mut hdr_job = settings(24, 20, 4, 16);
        hdr_job.environment = Some(EnvironmentSettings {
            strength: 2.5,
            rotation_degrees: 30.0,
            ..EnvironmentSettings::default()
        });
        let mut exr_job = settings(24, 20, 4, 8);
        exr_job.environment = Some(EnvironmentSettings {
            strength: 0.75,
            rotation_degrees: -100.0,
            ..EnvironmentSettings::default()
        });

        let mut jobs = Vec::new();
        let created = client
            .submit(scene.clone(), "cornell.gltf", &uniform)
            .await
            .unwrap();
        jobs.push((created.id, uniform.clone(), None));
        for (s, image, file) in [
            (&hdr_job, &hdr, "sky.hdr"),
            (&exr_job, &exr_image, "sky.exr"),
        ] {
            let created = client
                .submit_with_environment(
                    scene.clone(),
                    "cornell.gltf",
                    s,
                    Some((image.clone(), file.into())),
                )
                .await
                .unwrap_or_else(|e| panic!("{store}: {file}: {e}"));
            let mut s = s.clone();
            s.environment.as_mut().unwrap().image = Some(sha256(image));
            jobs.push((created.id, s, Some(image.clone())));
        }
        // The stored image again, named by its hash in the settings alone, turned otherwise.
        let mut by_hash = settings(24, 20, 4, 16);
        by_hash.environment = Some(EnvironmentSettings {
            image: Some(sha256(&hdr)),
            strength: 1.0,
            rotation_degrees: 200.0,
            ..EnvironmentSettings::default()
        });
        let created = client
            .submit(scene.clone(), "cornell.gltf", &by_hash)
            .await
            .unwrap();
        jobs.push((created.id, by_hash, Some(hdr.clone())));

        for (id, s, image) in &jobs {
            let done = wait_final(&client, id, Duration::from_secs(120)).await;
            assert_completed(&done);
            assert_eq!(
                done.settings.environment, s.environment,
                "{store}: the job view shows the environment it renders with"
            );
            let got = client.image_exr(id, false).await.unwrap();
            let expected = local_render_lit(&scene, s, image.as_deref());
            assert!(
                got == expected,
                "{store}: {:?}: the farm's image differs from the local render",
                s.environment
            );
            assert!(
                got != unlit,
                "{store}: {:?}: the environment changed nothing",
                s.environment
            );
            eprintln!("{store}: {:?}: identical", s.environment);
        }
        worker.stop().await;

        // A blob outlives a job only while another job uses it.
        let hdr_hash = sha256(&hdr);
        // From the store: over HTTP only a worker with a lease on a job of the blob may read it.
        let fetch = |hash: String| {
            let state = server.state.clone();
            async move { state.store.scene(&hash).await }
        };
        assert_eq!(fetch(hdr_hash.clone()).await.unwrap(), hdr);
        client.delete_job(&jobs[1].0).await.unwrap();
        assert_eq!(
            fetch(hdr_hash.clone()).await.unwrap(),
            hdr,
            "{store}: still used by the job that names it"
        );
        client.delete_job(&jobs[3].0).await.unwrap();
        let gone = fetch(hdr_hash).await.unwrap_err().to_string();
        assert!(gone.contains("not found"), "{store}: {gone}");
        server.stop().await;
    }
}

/// A submission body with an optional `environment` part.
fn multipart_with_environment(
    scene: &[u8],
    settings: &str,
    environment: Option<&[u8]>,
) -> (String, Vec<u8>) {
    let (ct, mut body) = multipart(scene, settings);
    if let Some(env) = environment {
        let boundary = "XpathfarmX";
        let end = format!("--{boundary}--\r\n");
        body.truncate(body.len() - end.len());
        body.extend_from_slice(format!("--{boundary}\r\nContent-Disposition: form-data; name=\"environment\"; filename=\"sky.hdr\"\r\nContent-Type: application/octet-stream\r\n\r\n").as_bytes());
        body.extend_from_slice(env);
        body.extend_from_slice(format!("\r\n{end}").as_bytes());
    }
    (ct, body)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn broken_unknown_and_contradictory_environments_are_422() {
    let scene = cornell();
    let hdr = hdr_sky(8, 4);
    let unknown = "0".repeat(64);
    let base = r#""width":8,"height":8,"spp":1"#;
    let with = |env: &str| format!("{{{base},\"environment\":{env}}}");
    for (store, url) in stores("environment-422").await {
        let state = pathfarm_server::AppState::open(config(&url)).await.unwrap();
        let cases: Vec<(String, Option<&[u8]>, &str, &str)> = vec![
            (
                format!("{{{base}}}"),
                Some(b"not an image at all"),
                "invalid_environment",
                "neither OpenEXR nor Radiance",
            ),
            (
                format!("{{{base}}}"),
                Some(&hdr[..hdr.len() / 2]),
                "invalid_environment",
                "Radiance",
            ),
            (
                format!("{{{base}}}"),
                Some(b""),
                "invalid_environment",
                "empty",
            ),
            (
                with(&format!(r#"{{"image":"{unknown}"}}"#)),
                None,
                "invalid_environment",
                "has no image",
            ),
            (
                with(&format!(r#"{{"radiance":[1,1,1],"image":"{unknown}"}}"#)),
                None,
                "invalid_settings",
                "not both",
            ),
            (
                with(r#"{"radiance":[1,1,1]}"#),
                Some(&hdr),
                "invalid_settings",
                "`radiance` given",
            ),
            (
                with(&format!(r#"{{"image":"{unknown}"}}"#)),
                Some(&hdr),
                "invalid_settings",
                "another image",
            ),
            (
                with(r#"{"strength":2}"#),
                None,
                "invalid_settings",
                "give `radiance` or `image`",
            ),
            (
                with(r#"{"radiance":[1,-1,1]}"#),
                None,
                "invalid_settings",
                "radiance must be finite and not negative",
            ),
            (
                with(r#"{"radiance":[1,1,1],"strength":1e39}"#),
                None,
                "invalid_settings",
                "strength must be finite",
            ),
            (
                with(r#"{"radiance":[1,1],"strength":1}"#),
                None,
                "invalid_settings",
                "invalid length 2",
            ),
            (
                with(r#"{"image":"ABC"}"#),
                None,
                "invalid_settings",
                "SHA-256",
            ),
        ];
        for (settings, env, code, says) in cases {
            let (ct, body) = multipart_with_environment(&scene, &settings, env);
            let (status, err) = call::<ErrorBody>(
                &state,
                request("POST", "/api/v1/jobs", &[("content-type", &ct)], body),
            )
            .await;
            assert_eq!(
                (status, err.error.code.as_str()),
                (StatusCode::UNPROCESSABLE_ENTITY, code),
                "{store}: {settings} with {:?} bytes: {}",
                env.map(<[u8]>::len),
                err.error.message
            );
            assert!(
                err.error.message.contains(says),
                "{store}: {settings}: {:?} does not say {says:?}",
                err.error.message
            );
        }
        let (status, list) = call::<JobList>(
            &state,
            request("GET", "/api/v1/jobs", &[], axum::body::Body::empty()),
        )
        .await;
        assert_eq!((status, list.total), (StatusCode::OK, 0), "{store}");
    }
}

/// The cornell box declaring an extension the tracer does not support (optional, so a warning).
fn cornell_with_unsupported_extension() -> Vec<u8> {
    let mut gltf: serde_json::Value = serde_json::from_slice(&cornell()).unwrap();
    let used = gltf
        .as_object_mut()
        .unwrap()
        .entry("extensionsUsed")
        .or_insert_with(|| serde_json::json!([]));
    used.as_array_mut()
        .unwrap()
        .push("KHR_materials_iridescence".into());
    serde_json::to_vec(&gltf).unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn scene_warnings_are_kept_with_the_job() {
    let scene = cornell_with_unsupported_extension();
    for (store, url) in stores("warnings").await {
        let server = TestServer::start(config(&url)).await;
        let client = server.client(None);
        let created = client
            .submit(scene.clone(), "iridescent.gltf", &settings(8, 8, 1, 8))
            .await
            .unwrap();
        let job: JobView = client.job(&created.id).await.unwrap();
        assert!(
            job.warnings
                .iter()
                .any(|w| w.contains("KHR_materials_iridescence")),
            "{store}: {:?}",
            job.warnings
        );
        let list = client.jobs(None, 1, 10).await.unwrap();
        assert_eq!(list.jobs[0].warnings, job.warnings, "{store}");
        // A scene without ignored features has none.
        let plain = client
            .submit(cornell(), "cornell.gltf", &settings(8, 8, 1, 8))
            .await
            .unwrap();
        let plain = client.job(&plain.id).await.unwrap();
        assert_eq!(plain.warnings, Vec::<String>::new(), "{store}");
        server.stop().await;
    }
}

#[test]
fn a_uniform_environment_is_radiance_times_strength() {
    // The one constructor the worker and `pathfarm render` share.
    let e = pathfarm_wire::build_environment(
        pathfarm_wire::EnvironmentSource::Radiance([0.3, 0.5, 0.8]),
        1.7,
        12.0,
    )
    .unwrap();
    assert_eq!(
        e.radiance(Vec3::X).to_array(),
        (Vec3::new(0.3, 0.5, 0.8) * 1.7).to_array()
    );
}
