use super::*;
use crate::image_budget::UNIT;
use axum::http::StatusCode;
use axum::response::IntoResponse;
use pathfarm_tracer::Accumulation;
use std::sync::atomic::AtomicUsize;

/// An image as a build leaves it: developed pixels, their room reserved in the cache's budget
/// (or none, when the budget has none left).
fn image(cache: &ImageCache, version: i64, width: u32, height: u32) -> Arc<JobImage> {
    let mut img = JobImage::of_accumulation(version, &Accumulation::new(0, 0, width, height));
    img.reserved = cache.hold(img.pixel_bytes()).unwrap_or_default();
    Arc::new(img)
}

/// What the images kept now hold, counted afresh: the cache's own count must equal it.
fn counted(cache: &ImageCache) -> usize {
    let resident = lock(&cache.shared.resident);
    resident.jobs.iter().map(|(id, e)| e.count(id)).sum()
}

fn kept(cache: &ImageCache) -> Vec<String> {
    let mut ids: Vec<String> = lock(&cache.shared.resident).jobs.keys().cloned().collect();
    ids.sort();
    ids
}

fn cache(budget: usize) -> ImageCache {
    ImageCache::new(budget, Duration::from_millis(100))
}

#[test]
fn an_entry_counts_its_pixels_and_encodings() {
    let cache = cache(1 << 20);
    let img = image(&cache, 1, 10, 20);
    assert_eq!(
        img.pixel_bytes(),
        200 * 20,
        "a developed pixel takes 20 bytes"
    );
    cache.keep("job", &img);
    let base = std::mem::size_of::<JobImage>() + 200 * 20 + 3;
    assert_eq!(cache.resident_bytes(), base);
    let room = cache.hold(1000).unwrap();
    let kept = cache.keep_encoding("job", &img, "png@0", &Bytes::from(vec![0; 1000]), room);
    assert!(kept.is_ok());
    assert_eq!(cache.resident_bytes(), base + 5 + 1000);
    assert_eq!(cache.resident_bytes(), counted(&cache));
}

/// Twenty images, room for three: a new image's room is made by letting the least recently used
/// kept image go (a read counts as a use), and the budget holds throughout.
#[test]
fn room_is_made_by_letting_the_least_recently_used_go() {
    let one = 32 * 32 * 20;
    let cache = cache(3 * one + one / 2);
    for i in 0..20 {
        let id = format!("job-{i:02}");
        let room = loop {
            if let Some(r) = cache.hold(one) {
                break r;
            }
            let gone = lock(&cache.shared.resident).evict_one();
            assert!(gone.is_some(), "{id}: nothing to let go");
        };
        let mut img = JobImage::of_accumulation(1, &Accumulation::new(0, 0, 32, 32));
        img.reserved = room;
        cache.keep(&id, &Arc::new(img));
        assert!(cache.reserved_bytes() <= cache.budget(), "after {id}");
        assert_eq!(cache.resident_bytes(), counted(&cache));
        if i >= 2 {
            // job-00 is read after each insertion: it stays.
            assert!(cache.kept("job-00", 1).is_some());
        }
    }
    assert_eq!(kept(&cache), ["job-00", "job-18", "job-19"]);
    cache.forget("job-18");
    assert_eq!(kept(&cache), ["job-00", "job-19"]);
    assert_eq!(cache.reserved_bytes(), 2 * one.div_ceil(UNIT) * UNIT);
}

/// An older version never replaces a newer one, an equal or newer version does; an image whose
/// pixels the budget could not hold is not kept, and the older version it supersedes goes.
#[test]
fn versions_and_images_over_the_budget() {
    let cache = cache(4 * 8 * 8 * 20 + 4 * UNIT);
    cache.keep("a", &image(&cache, 2, 8, 8));
    cache.keep("a", &image(&cache, 1, 8, 8));
    assert_eq!(cache.peek("a").unwrap().version, 2);
    let same = image(&cache, 2, 8, 8);
    cache.keep("a", &same);
    assert!(Arc::ptr_eq(&cache.peek("a").unwrap(), &same));
    cache.keep("a", &image(&cache, 3, 8, 8));
    assert_eq!(cache.peek("a").unwrap().version, 3);
    assert!(cache.kept("a", 4).is_none() && cache.kept("a", 3).is_some());
    cache.keep("b", &image(&cache, 1, 8, 8));
    cache.keep("b", &image(&cache, 2, 64, 64));
    assert!(cache.peek("b").is_none(), "over the budget: not kept");
    assert_eq!(kept(&cache), ["a"]);
    assert_eq!(cache.resident_bytes(), counted(&cache));
}

/// Encodings are made once per image and key, count against the budget and are kept while their
/// image is; one made for an image the cache does not hold is carried by that image alone.
#[tokio::test]
async fn encodings_are_made_once_and_kept_with_their_image() {
    let cache = cache(1 << 20);
    let (a, b) = (image(&cache, 1, 16, 16), image(&cache, 1, 16, 16));
    cache.keep("a", &a);
    let made = Arc::new(AtomicUsize::new(0));
    let encode = |n: usize| {
        let made = made.clone();
        move |_: &JobImage| -> ApiResult<Vec<u8>> {
            made.fetch_add(1, Ordering::Relaxed);
            Ok(vec![7; n])
        }
    };
    let before = cache.reserved_bytes();
    let bytes = cache
        .encoded("a", &a, "k", 1 << 16, encode(5000))
        .await
        .unwrap();
    assert_eq!(bytes.len(), 5000);
    assert_eq!(
        cache.reserved_bytes(),
        before + 5 * UNIT,
        "the kept bytes' room"
    );
    cache
        .encoded("a", &a, "k", 1 << 16, encode(1))
        .await
        .unwrap();
    assert_eq!(made.load(Ordering::Relaxed), 1);
    // Not kept in the cache: the image carries it (and its room) for whoever holds the image.
    for _ in 0..2 {
        cache
            .encoded("b", &b, "k", 1 << 16, encode(10))
            .await
            .unwrap();
    }
    assert_eq!(made.load(Ordering::Relaxed), 2);
    assert_eq!(cache.reserved_bytes(), before + 5 * UNIT + UNIT);
    let other = cache
        .encoded("b", &b, "other", 1 << 16, encode(20))
        .await
        .unwrap();
    assert_eq!(other.len(), 20, "one encoding carried: the last");
    assert_eq!(cache.reserved_bytes(), before + 5 * UNIT + UNIT);
    let b_room = b.reserved.bytes();
    drop(b);
    assert_eq!(
        cache.reserved_bytes(),
        before + 5 * UNIT - b_room,
        "the carried encoding's room goes with the image"
    );
    // A new image of the same version is a new build: encoded again.
    let b = image(&cache, 1, 16, 16);
    cache
        .encoded("b", &b, "k", 1 << 16, encode(10))
        .await
        .unwrap();
    assert_eq!(made.load(Ordering::Relaxed), 4);
    assert_eq!(cache.encodings(), 4);
    assert_eq!(cache.resident_bytes(), counted(&cache));
    drop((a, b));
    cache.forget("a");
    assert_eq!(cache.reserved_bytes(), 0, "everything given back");
}

/// With the budget taken, work waits, then is refused: 503 `busy` with `Retry-After`.
#[tokio::test]
async fn work_without_room_is_refused_with_retry_after() {
    let cache = cache(64 * UNIT);
    let all = cache.hold(usize::MAX).unwrap();
    let img = image(&cache, 1, 4, 4);
    let err = cache
        .encoded("a", &img, "k", 1000, |_| Ok(vec![1]))
        .await
        .unwrap_err();
    assert_eq!(
        (err.status, err.code),
        (StatusCode::SERVICE_UNAVAILABLE, "busy")
    );
    assert_eq!(cache.refused(), 1);
    let resp = err.into_response();
    assert_eq!(resp.headers()["retry-after"], "2");
    assert_eq!(resp.headers()["content-type"], "application/json");
    drop(all);
    let bytes = cache
        .encoded("a", &img, "k", 1000, |_| Ok(vec![1]))
        .await
        .unwrap();
    assert_eq!(&bytes[..], [1]);
}

/// The encoder runs on a blocking thread: on a runtime of one thread, it can wait for a task of
/// that runtime to run (were it run on the runtime's thread, that task could never run and the
/// wait would time out).
#[tokio::test(flavor = "current_thread")]
async fn encoding_leaves_the_runtime_free() {
    let cache = cache(1 << 20);
    let img = image(&cache, 1, 4, 4);
    cache.keep("a", &img);
    let (tx, rx) = std::sync::mpsc::channel::<()>();
    let other_request = tokio::spawn(async move { tx.send(()).unwrap() });
    let bytes = cache
        .encoded("a", &img, "k", 100, move |_| {
            rx.recv_timeout(std::time::Duration::from_secs(20))
                .map_err(|_| ApiError::internal("the runtime was blocked"))?;
            Ok(b"done".to_vec())
        })
        .await
        .unwrap();
    assert_eq!(&bytes[..], b"done");
    other_request.await.unwrap();
}

/// A panic while encoding is the API's usual 500 with a JSON error body, and the cache goes on
/// working.
#[tokio::test]
async fn a_panicking_encoder_is_an_internal_error() {
    let cache = cache(1 << 20);
    let img = image(&cache, 1, 4, 4);
    cache.keep("a", &img);
    let err = cache
        .encoded("a", &img, "k", 100, |_| panic!("encoder bug"))
        .await
        .unwrap_err();
    assert_eq!(
        (err.status, err.code),
        (StatusCode::INTERNAL_SERVER_ERROR, "internal")
    );
    assert!(err.message.starts_with("image encoding: "), "{err}");
    let resp = err.into_response();
    assert_eq!(resp.status(), StatusCode::INTERNAL_SERVER_ERROR);
    assert_eq!(resp.headers()["content-type"], "application/json");
    let bytes = cache
        .encoded("a", &img, "k", 100, |_| Ok(vec![1, 2, 3]))
        .await
        .unwrap();
    assert_eq!(&bytes[..], [1, 2, 3]);
    assert_eq!(cache.resident_bytes(), counted(&cache));
}

/// An image larger than the whole budget is not kept and leaves no room for its encoding: the
/// encoding is still made once for everyone who holds the image, and goes with it.
#[tokio::test]
async fn an_image_over_the_budget_carries_its_encoding() {
    let cache = cache(4 * UNIT);
    let mut img = JobImage::of_accumulation(1, &Accumulation::new(0, 0, 64, 64));
    assert!(img.pixel_bytes() > cache.budget());
    img.reserved = cache.hold(cache.budget()).unwrap();
    let img = Arc::new(img);
    cache.keep("big", &img);
    assert!(cache.peek("big").is_none(), "too large to keep");
    for _ in 0..3 {
        let bytes = cache
            .encoded("big", &img, "png", 10 * UNIT, |_| Ok(vec![1; 3 * UNIT]))
            .await
            .unwrap();
        assert_eq!(bytes.len(), 3 * UNIT);
    }
    assert_eq!(cache.encodings(), 1);
    assert_eq!(cache.reserved_bytes(), cache.budget());
    drop(img);
    assert_eq!(cache.reserved_bytes(), 0);
}
