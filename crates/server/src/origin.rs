//! The no-token mode on a workstation: a server without client tokens (`pathfarm up`, `serve` on
//! loopback) answers only requests addressed to it, and changes state only for its own pages.
//!
//! Without a token any local program may use the API, which is the point of the mode; but so
//! could any web page the user visits, through the browser: a cross-site form can POST to
//! `http://127.0.0.1:8080` (the browser sends no preflight for a form), and a page whose name
//! rebinds to 127.0.0.1 (DNS rebinding) is same-origin with the server from the browser's point
//! of view and can read what it likes. So, when no client token is configured:
//!
//! - **`Host`** must name this server: the listen address (IP and port), or `localhost`,
//!   `127.0.0.1` or `[::1]` with the listen port when listening on loopback. A rebinding page's
//!   requests carry its own name and are refused (403 `bad_host`), reads included. A request
//!   without `Host` (not from a browser: HTTP/1.1 browsers always send it) is let through.
//! - **`Origin`**, when present on a state-changing request (POST, PUT, PATCH, DELETE), must be
//!   the server's own origin: `http://` (`https://` when the server terminates TLS itself) and a
//!   host and port `Host` would accept. `Origin: null`
//!   (sandboxed pages, some redirects) is refused, and so is a `Sec-Fetch-Site` of `cross-site`
//!   or `same-site`, which browsers send beside it (403 `cross_origin`).
//!
//! Workers, the CLI and other programs send no `Origin` and the address they were given as
//! `Host`; the dashboard is served by the server itself and sends its own origin. `/healthz` and
//! `/readyz` reveal nothing and are never checked. With client tokens configured the check is off:
//! a page cannot know a token.

use crate::error::ApiError;
use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, Method};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};

/// Who the server is, for the checks.
#[derive(Clone, Copy, Debug)]
pub struct OwnOrigin {
    /// The address the server listens on; `None` when unknown (a router used without a
    /// listener, as in tests): then any port is accepted with the loopback names.
    pub listen: Option<SocketAddr>,
    /// Whether the server terminates TLS itself: its pages' origin is then `https://`, and a
    /// `Host` or origin without a port means 443. (Behind a TLS proxy the server sees plain HTTP
    /// and the proxy's `Host`, as before.)
    pub tls: bool,
}

/// A host and port as `Host` or an origin's authority gives them: the name lowercased, an IPv6
/// address without its brackets, the port when given.
fn split_authority(authority: &str) -> Option<(String, Option<u16>)> {
    let authority = authority.trim();
    let (host, port) = if let Some(rest) = authority.strip_prefix('[') {
        let (v6, after) = rest.split_once(']')?;
        match after {
            "" => (v6, None),
            p => (v6, Some(p.strip_prefix(':')?)),
        }
    } else {
        match authority.rsplit_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (authority, None),
        }
    };
    if host.is_empty() {
        return None;
    }
    let port = match port {
        Some(p) => Some(p.parse::<u16>().ok()?),
        None => None,
    };
    Some((host.to_ascii_lowercase(), port))
}

impl OwnOrigin {
    /// The scheme of this server's own pages.
    fn scheme(&self) -> &'static str {
        if self.tls {
            "https://"
        } else {
            "http://"
        }
    }

    /// The port a `Host` or origin without one means.
    fn default_port(&self) -> u16 {
        if self.tls {
            443
        } else {
            80
        }
    }

    /// Whether `host` (a name or IP address, lowercase, IPv6 unbracketed) names this server.
    fn host_is_mine(&self, host: &str) -> bool {
        let ip = host.parse::<IpAddr>().ok();
        let listen_ip = self.listen.map(|a| a.ip());
        let on_loopback = listen_ip.is_none_or(|ip| ip.is_loopback() || ip.is_unspecified());
        let loopback_name = host == "localhost"
            || ip == Some(IpAddr::V4(Ipv4Addr::LOCALHOST))
            || ip == Some(IpAddr::V6(Ipv6Addr::LOCALHOST));
        (on_loopback && loopback_name)
            || (ip.is_some() && ip == listen_ip)
            // Listening on every address: any address of this machine, never a name (a
            // rebinding page has a name).
            || (ip.is_some() && listen_ip.is_some_and(|l| l.is_unspecified()))
    }

    /// Whether `host` and `port` (absent: the scheme's default, 80 or 443) address this server.
    fn addresses_me(&self, host: &str, port: Option<u16>) -> bool {
        let port_ok = match self.listen {
            Some(listen) => port.unwrap_or(self.default_port()) == listen.port(),
            None => true,
        };
        port_ok && self.host_is_mine(host)
    }

    /// What `Host` may name (each prefixed with `scheme`), for messages.
    fn accepted(&self, scheme: &str) -> String {
        let mut names = Vec::new();
        let loopback = ["localhost", "127.0.0.1", "[::1]"];
        match self.listen {
            Some(a) => {
                names.push(a.to_string());
                if a.ip().is_loopback() || a.ip().is_unspecified() {
                    names.extend(loopback.map(|h| format!("{h}:{}", a.port())));
                }
            }
            None => names.extend(loopback.map(String::from)),
        }
        let mut unique: Vec<String> = Vec::new();
        for n in names.iter().map(|n| format!("{scheme}{n}")) {
            if !unique.contains(&n) {
                unique.push(n);
            }
        }
        match unique.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            _ => unique.concat(),
        }
    }

    /// The request's `Host` (or, without one, its URI's authority, as HTTP/2 carries it).
    fn check_host(&self, req: &Request) -> Result<(), ApiError> {
        let given = match req.headers().get(header::HOST) {
            Some(v) => Some(v.to_str().unwrap_or("(not text)").to_string()),
            None => req.uri().authority().map(|a| a.to_string()),
        };
        let Some(given) = given else {
            return Ok(());
        };
        match split_authority(&given) {
            Some((host, port)) if self.addresses_me(&host, port) => Ok(()),
            _ => Err(ApiError::forbidden(
                "bad_host",
                format!(
                    "Host {given:?} does not name this server, which has no client token and \
                     answers only to {}",
                    self.accepted("")
                ),
            )),
        }
    }

    /// `Origin` and `Sec-Fetch-Site` of a state-changing request.
    fn check_origin(&self, headers: &HeaderMap) -> Result<(), ApiError> {
        let refuse = |what: String| {
            Err(ApiError::forbidden(
                "cross_origin",
                format!(
                    "{what}: this server has no client token and changes state only for its own \
                     pages ({})",
                    self.accepted(self.scheme())
                ),
            ))
        };
        if let Some(site) = headers.get("sec-fetch-site") {
            let site = site.to_str().unwrap_or("");
            if !matches!(site, "same-origin" | "none") {
                return refuse(format!(
                    "a request from another site (Sec-Fetch-Site: {site:?})"
                ));
            }
        }
        let Some(origin) = headers.get(header::ORIGIN) else {
            return Ok(());
        };
        let origin = origin.to_str().unwrap_or("(not text)");
        let mine = origin
            .strip_prefix(self.scheme())
            .and_then(split_authority)
            .is_some_and(|(host, port)| {
                let same_port = match (self.listen, headers.get(header::HOST)) {
                    // Port unknown: the one the request was sent to.
                    (None, Some(h)) => {
                        h.to_str()
                            .ok()
                            .and_then(split_authority)
                            .is_some_and(|(_, p)| {
                                let default = self.default_port();
                                p.unwrap_or(default) == port.unwrap_or(default)
                            })
                    }
                    _ => true,
                };
                same_port && self.addresses_me(&host, port)
            });
        if mine {
            Ok(())
        } else {
            refuse(format!(
                "a request from the page of another origin ({origin:?})"
            ))
        }
    }
}

fn changes_state(method: &Method) -> bool {
    matches!(
        *method,
        Method::POST | Method::PUT | Method::PATCH | Method::DELETE
    )
}

/// Middleware: the checks above (installed only when no client token is configured).
pub async fn guard(State(own): State<OwnOrigin>, req: Request, next: Next) -> Response {
    if matches!(req.uri().path(), "/healthz" | "/readyz") {
        return next.run(req).await;
    }
    let checked = own.check_host(&req).and_then(|()| {
        if changes_state(req.method()) {
            own.check_origin(req.headers())
        } else {
            Ok(())
        }
    });
    match checked {
        Ok(()) => next.run(req).await,
        Err(e) => {
            tracing::warn!(
                method = %req.method(),
                path = req.uri().path(),
                code = e.code,
                "refused: {}",
                e.message
            );
            e.into_response()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(addr: &str) -> OwnOrigin {
        OwnOrigin {
            listen: Some(addr.parse().unwrap()),
            tls: false,
        }
    }

    #[test]
    fn authorities_split() {
        assert_eq!(
            split_authority("LocalHost:8080"),
            Some(("localhost".into(), Some(8080)))
        );
        assert_eq!(split_authority("[::1]:9"), Some(("::1".into(), Some(9))));
        assert_eq!(split_authority("[::1]"), Some(("::1".into(), None)));
        assert_eq!(
            split_authority("x.example"),
            Some(("x.example".into(), None))
        );
        assert_eq!(split_authority("x:99999"), None);
        assert_eq!(split_authority(":80"), None);
        assert_eq!(split_authority("[::1]x"), None);
    }

    #[test]
    fn hosts_on_loopback() {
        let own = at("127.0.0.1:8080");
        for ok in ["127.0.0.1:8080", "localhost:8080", "[::1]:8080"] {
            let (h, p) = split_authority(ok).unwrap();
            assert!(own.addresses_me(&h, p), "{ok}");
        }
        for bad in [
            "evil.example:8080",
            "127.0.0.1:8081",
            "localhost",
            "127.0.0.2:8080",
            "localhost.evil.example:8080",
        ] {
            let (h, p) = split_authority(bad).unwrap();
            assert!(!own.addresses_me(&h, p), "{bad}");
        }
        // Elsewhere: only the listen address itself.
        let own = at("10.1.2.3:80");
        assert!(own.addresses_me("10.1.2.3", None));
        assert!(!own.addresses_me("localhost", Some(80)));
        // Unknown listen address: loopback names on any port.
        let own = OwnOrigin {
            listen: None,
            tls: false,
        };
        assert!(own.addresses_me("localhost", Some(1234)));
        assert!(!own.addresses_me("evil.example", Some(1234)));
    }

    #[test]
    fn messages_name_each_accepted_address_once() {
        assert_eq!(
            at("127.0.0.1:80").accepted("http://"),
            "http://127.0.0.1:80, http://localhost:80 or http://[::1]:80"
        );
        assert_eq!(at("10.0.0.1:9").accepted(""), "10.0.0.1:9");
        assert_eq!(
            OwnOrigin {
                listen: None,
                tls: false,
            }
            .accepted(""),
            "localhost, 127.0.0.1 or [::1]"
        );
    }

    #[test]
    fn origins() {
        let own = at("127.0.0.1:8080");
        let headers = |pairs: &[(&'static str, &str)]| {
            let mut h = HeaderMap::new();
            for (k, v) in pairs {
                h.insert(*k, v.parse().unwrap());
            }
            h
        };
        assert!(own.check_origin(&headers(&[])).is_ok());
        assert!(own
            .check_origin(&headers(&[("origin", "http://localhost:8080")]))
            .is_ok());
        assert!(own
            .check_origin(&headers(&[
                ("origin", "http://127.0.0.1:8080"),
                ("sec-fetch-site", "same-origin")
            ]))
            .is_ok());
        for bad in [
            "http://evil.example",
            "null",
            "https://127.0.0.1:8080",
            "http://127.0.0.1:3000",
        ] {
            let err = own.check_origin(&headers(&[("origin", bad)])).unwrap_err();
            assert_eq!(err.code, "cross_origin", "{bad}");
            assert!(err.message.contains(bad), "{}", err.message);
        }
        let err = own
            .check_origin(&headers(&[("sec-fetch-site", "cross-site")]))
            .unwrap_err();
        assert!(err.message.contains("cross-site"));
    }

    #[test]
    fn a_tls_server_s_origin_is_https() {
        let own = OwnOrigin {
            listen: Some("127.0.0.1:8443".parse().unwrap()),
            tls: true,
        };
        let origin = |o: &str| {
            let mut h = HeaderMap::new();
            h.insert("origin", o.parse().unwrap());
            own.check_origin(&h)
        };
        assert!(origin("https://localhost:8443").is_ok());
        assert!(origin("https://127.0.0.1:8443").is_ok());
        let err = origin("http://127.0.0.1:8443").unwrap_err();
        assert!(
            err.message.contains("https://127.0.0.1:8443"),
            "{}",
            err.message
        );
        // Without a port, an https origin means 443.
        let on_443 = OwnOrigin {
            listen: Some("127.0.0.1:443".parse().unwrap()),
            tls: true,
        };
        assert!(on_443.addresses_me("localhost", None));
        assert!(!own.addresses_me("localhost", None));
    }
}
