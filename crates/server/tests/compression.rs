//! Response compression: JSON lists and the metrics text go out gzip- or zstd-encoded to a client
//! that accepts it, identical once decoded; images and scenes go out as they are; a client that
//! accepts no encoding gets none. The project's own client (reqwest with gzip and zstd) decodes.

mod common;

use common::*;

/// Submits enough jobs for the list to be worth compressing.
async fn server_with_jobs() -> (TestServer, Vec<String>) {
    let dir = temp_dir("compression");
    let server = TestServer::start(config(&format!(
        "sqlite://{}",
        dir.join("db.sqlite").display()
    )))
    .await;
    let client = server.client(None);
    let mut ids = Vec::new();
    for _ in 0..12 {
        let job = client
            .submit(cornell(), "cornell.gltf", &settings(16, 16, 1, 16))
            .await
            .unwrap();
        ids.push(job.id);
    }
    (server, ids)
}

/// A client that neither asks for nor decodes any encoding: what goes over the wire.
fn raw() -> reqwest::Client {
    reqwest::Client::builder()
        .no_gzip()
        .no_zstd()
        .build()
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn lists_and_metrics_are_compressed_for_clients_that_accept_it() {
    let (server, ids) = server_with_jobs().await;
    for path in ["/api/v1/jobs", "/metrics"] {
        let url = format!("{}{path}", server.url);
        let plain = raw().get(&url).send().await.unwrap();
        assert_eq!(plain.status().as_u16(), 200);
        assert!(plain.headers().get("content-encoding").is_none(), "{path}");
        let plain = plain.bytes().await.unwrap();
        for (encoding, magic) in [
            ("gzip", &[0x1f, 0x8b][..]),
            ("zstd", &[0x28, 0xb5, 0x2f, 0xfd][..]),
        ] {
            let resp = raw()
                .get(&url)
                .header("accept-encoding", encoding)
                .send()
                .await
                .unwrap();
            assert_eq!(resp.status().as_u16(), 200);
            assert_eq!(
                resp.headers()["content-encoding"].to_str().unwrap(),
                encoding,
                "{path}"
            );
            let body = resp.bytes().await.unwrap();
            assert!(body.starts_with(magic), "{path} {encoding}");
            if path == "/api/v1/jobs" {
                assert!(
                    body.len() * 3 < plain.len(),
                    "{path} {encoding}: {} of {} bytes",
                    body.len(),
                    plain.len()
                );
            }
        }
    }
    // The project's client asks for both and decodes: the same list as an identity response.
    let decoded: serde_json::Value = reqwest::get(format!("{}/api/v1/jobs", server.url))
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let identity: serde_json::Value = raw()
        .get(format!("{}/api/v1/jobs", server.url))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(decoded, identity);
    assert_eq!(decoded["jobs"].as_array().map(Vec::len), Some(ids.len()));
    server.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn images_are_sent_as_they_are() {
    let dir = temp_dir("compression-images");
    let server = TestServer::start(config(&format!(
        "sqlite://{}",
        dir.join("db.sqlite").display()
    )))
    .await;
    let client = server.client(None);
    let job = client
        .submit(cornell(), "cornell.gltf", &settings(64, 64, 2, 32))
        .await
        .unwrap();
    let worker = TestWorker::spawn(&server.url, None, None);
    let done = wait_final(&client, &job.id, std::time::Duration::from_secs(60)).await;
    worker.stop().await;
    assert_completed(&done);
    for path in ["preview.png", "image.exr"] {
        let url = format!("{}/api/v1/jobs/{}/{path}", server.url, job.id);
        let resp = raw()
            .get(&url)
            .header("accept-encoding", "gzip, zstd")
            .send()
            .await
            .unwrap();
        assert_eq!(resp.status().as_u16(), 200, "{path}");
        assert!(
            resp.headers().get("content-encoding").is_none(),
            "{path}: {:?}",
            resp.headers()
        );
        let body = resp.bytes().await.unwrap();
        assert!(body.len() > 1000, "{path}: {} bytes", body.len());
    }
    server.stop().await;
}
