//! # pathfarm-server
//!
//! The render farm server: the REST API of `openapi.yaml` ([`app`]), the job queue and scheduler,
//! task leases with fencing tokens, and the exact progressive merge of the slices workers upload.
//! State lives in the store (SQLite or PostgreSQL, see [`store`]); the process keeps only caches, so
//! several servers can share one PostgreSQL database and serve one farm.

pub mod auth;
pub mod body_budget;
mod compression;
pub mod config;
pub mod connections;
pub mod dashboard;
pub mod error;
pub mod heatmap;
pub mod image_budget;
pub mod image_cache;
pub mod job_image;
pub mod metrics;
pub mod monitor;
pub mod origin;
pub mod pacing;
mod process_metrics;
pub mod routes;
pub mod scheduler;
pub mod single_flight;
pub mod states;
pub mod store;
pub mod tls;
pub mod work_signal;

pub use config::{ConnectionLimits, Limits, Quotas, ServerConfig, SqliteSynchronous};
pub use store::Store;

use axum::extract::DefaultBodyLimit;
use axum::http::StatusCode;
use axum::Router;
use error::ApiError;
use std::future::Future;
use std::sync::Arc;

/// Shared by every request handler.
#[derive(Clone)]
pub struct AppState(Arc<Inner>);

pub struct Inner {
    pub store: Store,
    pub config: ServerConfig,
    pub images: image_cache::ImageCache,
    pub metrics: metrics::Metrics,
    /// Permits to validate a submitted scene ([`config::Limits::scene_checks`]).
    pub scene_checks: tokio::sync::Semaphore,
    /// The bodies held in memory at once ([`config::Limits::body_budget_bytes`]).
    pub bodies: body_budget::BodyBudget,
    /// The slice length asked of workers ([`ServerConfig::target_write_load`]).
    pub pacing: pacing::Pacing,
    /// When each running job's error was last estimated, and what it cost ([`monitor`]).
    pub estimates: monitor::EstimateClock,
    /// Wakes lease requests waiting for work ([`work_signal`]).
    pub work: work_signal::WorkSignal,
}

impl std::ops::Deref for AppState {
    type Target = Inner;
    fn deref(&self) -> &Inner {
        &self.0
    }
}

impl AppState {
    /// Opens the store (applying migrations) and builds the state.
    pub async fn open(config: ServerConfig) -> Result<AppState, store::StoreError> {
        let store = Store::connect_with(
            &config.db_url,
            config.clock.clone(),
            config.sqlite_synchronous,
        )
        .await?
        .with_verify_fraction(config.verify_fraction);
        let scene_checks = tokio::sync::Semaphore::new(config.limits.scene_checks.max(1));
        let bodies =
            body_budget::BodyBudget::new(config.limits.body_budget_bytes, config.limits.body_wait);
        let images = image_cache::ImageCache::new(config.image_cache_bytes, config.image_wait);
        let pacing = pacing::Pacing::new(config.target_write_load);
        Ok(AppState(Arc::new(Inner {
            store,
            pacing,
            scene_checks,
            bodies,
            config,
            images,
            metrics: Default::default(),
            estimates: Default::default(),
            work: Default::default(),
        })))
    }
}

/// The router: every route of [`routes::api_routes`], JSON errors for unknown paths and methods.
/// Without client tokens, requests must name this server and state changes come from its own
/// origin ([`origin`]); the listen address is not known here, so `Host` may give any port with
/// the loopback names ([`app_listening_on`] knows it, and [`serve`] uses that).
pub fn app(state: AppState) -> Router {
    router(state, None)
}

/// [`app`] for a server listening on `listen`: without client tokens, `Host` must name that
/// address (or a loopback name with its port when it is a loopback address).
pub fn app_listening_on(state: AppState, listen: std::net::SocketAddr) -> Router {
    router(state, Some(listen))
}

fn router(state: AppState, listen: Option<std::net::SocketAddr>) -> Router {
    // Each route reads at most its own limit (see `routes::body_limit`): a worker's heartbeat
    // cannot send a scene-sized body, nor a slice upload more than the slice limit.
    let mut router = Router::new();
    for r in routes::api_routes() {
        let limit = routes::body_limit(&r.method, r.path, &state.config.limits);
        let reason = routes::body_limit_reason(&r.method, r.path, &state.config.limits);
        let handler = r.handler.layer(DefaultBodyLimit::max(limit)).layer(
            axum::middleware::from_fn_with_state(
                (limit, std::sync::Arc::<str>::from(reason)),
                connections::declared_length,
            ),
        );
        router = router.route(r.path, handler);
    }
    let router = router
        .route_layer(axum::middleware::from_fn_with_state(
            state.clone(),
            routes::metrics::track_latency,
        ))
        .merge(dashboard::router())
        .fallback(|| async {
            ApiError::new(StatusCode::NOT_FOUND, "not_found", "no such endpoint")
        })
        .method_not_allowed_fallback(|| async {
            ApiError::new(
                StatusCode::METHOD_NOT_ALLOWED,
                "method_not_allowed",
                "method not allowed on this endpoint",
            )
        })
        .layer(axum::middleware::from_fn(routes::nul_paths));
    let router = if state.config.client_tokens.is_empty() {
        router.layer(axum::middleware::from_fn_with_state(
            origin::OwnOrigin {
                listen,
                tls: state.config.tls.is_some(),
            },
            origin::guard,
        ))
    } else {
        router
    };
    router
        .layer(axum::middleware::map_response(error::json_errors))
        .layer(compression::layer())
        .layer(DefaultBodyLimit::max(config::MAX_JSON_BODY_BYTES))
        .layer(tower_http::trace::TraceLayer::new_for_http())
        .layer(axum::middleware::from_fn_with_state(
            state.clone(),
            connections::track,
        ))
        .with_state(state)
}

/// Serves the API on `listener` until `shutdown` resolves, running the monitor loop alongside;
/// in-flight requests finish before it returns. Connections are held to the timeouts and the cap
/// of [`ConnectionLimits`] ([`connections`]). With [`ServerConfig::tls`] every connection is
/// HTTPS, and the certificate files are watched for changes ([`tls::watch`]).
pub async fn serve(
    state: AppState,
    listener: tokio::net::TcpListener,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    let listen = listener.local_addr()?;
    let tls = match &state.config.tls {
        Some(cert) => {
            let config = cert.server_config().map_err(std::io::Error::other)?;
            Some((
                tokio_rustls::TlsAcceptor::from(Arc::new(config)),
                tokio::spawn(tls::watch(cert.clone())),
            ))
        }
        None => None,
    };
    let monitor = tokio::spawn(monitor::run(state.clone()));
    let listener = connections::GuardedListener::new(
        listener,
        state.clone(),
        tls.as_ref().map(|(acceptor, _)| acceptor.clone()),
    );
    let app = app_listening_on(state.clone(), listen)
        .into_make_service_with_connect_info::<connections::ConnHandle>();
    // Waiting lease requests answer at once when shutdown begins: in-flight requests are waited
    // for, and a long poll would hold shutdown up for its whole wait.
    let closing = state.clone();
    let shutdown = async move {
        shutdown.await;
        closing.work.close();
    };
    let result = axum::serve(listener, app)
        .with_graceful_shutdown(shutdown)
        .await;
    monitor.abort();
    if let Some((_, watcher)) = tls {
        watcher.abort();
    }
    state.store.close().await;
    result
}
