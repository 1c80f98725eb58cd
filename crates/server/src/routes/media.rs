//! The media type of a binary download, negotiated with the request's `Accept`.
//!
//! Every binary download (EXR, PNG, APNG, tar) has its own media type, and the contract lists
//! `application/octet-stream` beside it: client generators understand that one as "bytes" and
//! leave the others out. A client whose `Accept` takes `application/octet-stream` but not the
//! download's own type (nor a wildcard that covers it) gets the same bytes labelled
//! `application/octet-stream`; everyone else, a request without `Accept` or with `*/*` included,
//! gets the download's own type. Nothing is ever refused with 406: the bytes are the same.

use axum::http::{header, HeaderMap};

/// The generic binary media type offered beside each download's own.
pub const OCTET_STREAM: &str = "application/octet-stream";

/// The media type to label a download of type `native` with, for a request with `headers`.
pub fn binary_type(headers: &HeaderMap, native: &'static str) -> &'static str {
    let Some(accept) = headers.get(header::ACCEPT).and_then(|v| v.to_str().ok()) else {
        return native;
    };
    let (native_top, _) = native.split_once('/').unwrap_or((native, ""));
    let (mut takes_native, mut takes_octets) = (false, false);
    for range in accept.split(',') {
        let mut parts = range.split(';');
        let ty = parts.next().unwrap_or("").trim().to_ascii_lowercase();
        let refused = parts.any(|p| {
            p.trim()
                .strip_prefix("q=")
                .and_then(|q| q.trim().parse::<f32>().ok())
                .is_some_and(|q| q <= 0.0)
        });
        if refused {
            continue;
        }
        let covers_native =
            ty == native || ty == "*/*" || ty.strip_suffix("/*") == Some(native_top);
        takes_native |= covers_native;
        takes_octets |= ty == OCTET_STREAM;
    }
    if takes_octets && !takes_native {
        OCTET_STREAM
    } else {
        native
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    fn with_accept(accept: Option<&str>) -> HeaderMap {
        let mut h = HeaderMap::new();
        if let Some(a) = accept {
            h.insert(header::ACCEPT, HeaderValue::from_str(a).unwrap());
        }
        h
    }

    #[test]
    fn octets_only_for_a_client_that_asks_for_them_and_not_for_the_native_type() {
        let cases = [
            (None, "image/png"),
            (Some("*/*"), "image/png"),
            (Some("image/png"), "image/png"),
            (Some("image/*"), "image/png"),
            (Some("application/octet-stream"), OCTET_STREAM),
            (Some("Application/Octet-Stream; q=0.9"), OCTET_STREAM),
            (Some("application/octet-stream, */*;q=0.1"), "image/png"),
            (
                Some("application/octet-stream, image/png;q=0"),
                OCTET_STREAM,
            ),
            (Some("application/octet-stream;q=0, image/png"), "image/png"),
            (Some("application/json"), "image/png"),
        ];
        for (accept, want) in cases {
            assert_eq!(
                binary_type(&with_accept(accept), "image/png"),
                want,
                "Accept: {accept:?}"
            );
        }
    }
}
