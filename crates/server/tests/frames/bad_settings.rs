//! Bad frame specifications are answered 4xx naming the field.

use super::*;

#[tokio::test]
async fn bad_frame_settings_are_4xx_naming_the_field() {
    for (store, url) in stores("frames-bad").await {
        let server = TestServer::start(config(&url)).await;
        let scene = animated();
        for (settings, field) in [
            (r#"{"width":8,"height":8,"spp":1,"frames":"5-1"}"#, "frames"),
            (r#"{"width":8,"height":8,"spp":1,"frames":""}"#, "frames"),
            (r#"{"width":8,"height":8,"spp":1,"frames":"1,x"}"#, "frames"),
            (
                r#"{"width":8,"height":8,"spp":1,"frames":"0-99999"}"#,
                "frames",
            ),
            (
                r#"{"width":8,"height":8,"spp":1,"frames":"1-3,2"}"#,
                "frames",
            ),
            // A wrong JSON type is serde's message, as for every settings field.
            (
                r#"{"width":8,"height":8,"spp":1,"frames":7}"#,
                "expected a string",
            ),
            (
                r#"{"width":8,"height":8,"spp":1,"frames":"1-3","fps":0}"#,
                "fps",
            ),
            (
                r#"{"width":8,"height":8,"spp":1,"frames":"1-3","fps":-24}"#,
                "fps",
            ),
            (r#"{"width":8,"height":8,"spp":1,"fps":24}"#, "fps"),
            (
                r#"{"width":8,"height":8,"spp":1,"frames":"1","frame_order":"random"}"#,
                "expected `interleaved` or `sequential`",
            ),
        ] {
            let (ct, body) = multipart(&scene, settings);
            let (status, err): (StatusCode, ErrorBody) = call(
                &server.state,
                request("POST", "/api/v1/jobs", &[("content-type", &ct)], body),
            )
            .await;
            assert!(status.is_client_error(), "{store}: {settings}: {status}");
            assert!(
                err.error.message.contains(field),
                "{store}: {settings}: {}",
                err.error.message
            );
        }
        // A frame that is not the job's, and a frame of a still job, are 4xx too.
        let client = server.client(None);
        let job = client
            .submit(scene.clone(), "a.glb", &frame_settings("1-2", None, 8))
            .await
            .unwrap();
        let still = client
            .submit(cornell(), "c.gltf", &settings(8, 8, 1, 8))
            .await
            .unwrap();
        // A frame the job does not have is not found (a still job has none); a frame that is
        // not an integer is a bad query.
        for (id, q, want) in [
            (&job.id, "frame=3", StatusCode::NOT_FOUND),
            (&job.id, "frame=x", StatusCode::BAD_REQUEST),
            (&still.id, "frame=1", StatusCode::NOT_FOUND),
        ] {
            for image in ["image.exr", "preview.png", "convergence"] {
                let (status, _): (StatusCode, ErrorBody) = call(
                    &server.state,
                    request("GET", &format!("/api/v1/jobs/{id}/{image}?{q}"), &[], ""),
                )
                .await;
                assert_eq!(status, want, "{store}: {image}?{q}");
            }
        }
        let view = client.job(&still.id).await.unwrap();
        assert_eq!((view.frames_total, view.frames_done), (None, None));
        assert!(view.state != JobState::Failed);
        server.stop().await;
    }
}
