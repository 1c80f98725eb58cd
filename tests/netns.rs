//! Several hosts on one machine: the server and two workers each in a network namespace of its
//! own (`ip netns`), joined by veth pairs, so the workers reach the server over a virtual network
//! and not over loopback. One worker's link is cut in the middle of a task and brought back: the
//! job still completes bit-identical to a local render, no sample is merged twice, and the cut
//! worker recovers and merges new work.
//!
//! Needs root (CI runs as root). Elsewhere it prints `SKIPPED`; with `PATHFARM_REQUIRE_NETNS=1`
//! (set by `.ci/run`) a missing capability is a failure instead.
//!
//! ```text
//!   test process (root namespace) 10.N.0.1 ──veth── 10.N.0.2  ┌ pf…-srv: pathfarm serve :8080
//!                 pf…-w1: worker 10.N.1.2 ──veth── 10.N.1.1  ┤   (the cut: this link, server side)
//!                 pf…-w2: worker 10.N.2.2 ──veth── 10.N.2.1  ┘
//! ```

mod support;

use pathfarm_wire::api::WorkerState;
use pathfarm_worker::client::ApiClient;
use std::net::SocketAddr;
use std::process::Command;
use std::time::Duration;
use support::*;

const PORT: u16 = 8080;
const CLIENT_TOKEN: &str = "netns-client-secret";
const WORKER_TOKEN: &str = "netns-worker-secret";

/// Runs `ip ARGS…`; an error says which command failed and why.
fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip {}: {e}", args.join(" ")))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// The namespaces and links of one test, removed when dropped (deleting a namespace deletes the
/// veth ends inside it, and with them their peers).
struct Network {
    /// Short prefix of every name (interface names are limited to 15 bytes).
    tag: String,
    /// Second octet of every address: 10.N.x.y.
    net: u8,
    namespaces: Vec<String>,
}

impl Network {
    fn ns(&self, role: &str) -> String {
        format!("{}-{role}", self.tag)
    }

    fn addr(&self, link: u8, host: u8) -> String {
        format!("10.{}.{link}.{host}", self.net)
    }

    /// Builds the topology of the module docs.
    fn build() -> Result<Network, String> {
        let pid = std::process::id();
        let mut n = Network {
            tag: format!("pf{}", pid % 100_000),
            net: 200 + (pid % 50) as u8,
            namespaces: Vec::new(),
        };
        for role in ["srv", "w1", "w2"] {
            let ns = n.ns(role);
            let _ = ip(&["netns", "del", &ns]); // a leftover of an earlier crash
            ip(&["netns", "add", &ns])?;
            n.namespaces.push(ns.clone());
            ip(&["-n", &ns, "link", "set", "lo", "up"])?;
        }
        let srv = n.ns("srv");
        // The test's own link to the server (root namespace ↔ srv).
        let host_end = format!("{}h", n.tag);
        let srv_end = format!("{}s0", n.tag);
        let _ = ip(&["link", "del", &host_end]);
        ip(&[
            "link", "add", &host_end, "type", "veth", "peer", "name", &srv_end,
        ])?;
        ip(&["link", "set", &srv_end, "netns", &srv])?;
        ip(&[
            "addr",
            "add",
            &format!("{}/24", n.addr(0, 1)),
            "dev",
            &host_end,
        ])?;
        ip(&["link", "set", &host_end, "up"])?;
        ip(&[
            "-n",
            &srv,
            "addr",
            "add",
            &format!("{}/24", n.addr(0, 2)),
            "dev",
            &srv_end,
        ])?;
        ip(&["-n", &srv, "link", "set", &srv_end, "up"])?;
        // One link per worker host.
        for k in 1..=2u8 {
            let wns = n.ns(&format!("w{k}"));
            let (s_end, w_end) = (format!("{}s{k}", n.tag), format!("{}w{k}", n.tag));
            ip(&[
                "-n", &srv, "link", "add", &s_end, "type", "veth", "peer", "name", &w_end,
            ])?;
            ip(&["-n", &srv, "link", "set", &w_end, "netns", &wns])?;
            ip(&[
                "-n",
                &srv,
                "addr",
                "add",
                &format!("{}/24", n.addr(k, 1)),
                "dev",
                &s_end,
            ])?;
            ip(&["-n", &srv, "link", "set", &s_end, "up"])?;
            ip(&[
                "-n",
                &wns,
                "addr",
                "add",
                &format!("{}/24", n.addr(k, 2)),
                "dev",
                &w_end,
            ])?;
            ip(&["-n", &wns, "link", "set", &w_end, "up"])?;
        }
        Ok(n)
    }

    /// Takes the server's end of worker `k`'s link down (`up = false`) or up again. Packets on a
    /// veth whose peer is down are dropped silently, as on a cut cable: the worker sees no error,
    /// only silence.
    fn set_worker_link(&self, k: u8, up: bool) -> Result<(), String> {
        let end = format!("{}s{k}", self.tag);
        let state = if up { "up" } else { "down" };
        ip(&["-n", &self.ns("srv"), "link", "set", &end, state])
    }

    fn server_url_for_worker(&self, k: u8) -> String {
        format!("http://{}:{PORT}", self.addr(k, 1))
    }

    fn server_url(&self) -> String {
        format!("http://{}:{PORT}", self.addr(0, 2))
    }
}

impl Drop for Network {
    fn drop(&mut self) {
        for ns in &self.namespaces {
            let _ = ip(&["netns", "del", ns]);
        }
        let _ = ip(&["link", "del", &format!("{}h", self.tag)]);
    }
}

/// Whether this machine can build namespaces; `Err` says why not.
fn network_or_skip() -> Option<Network> {
    // SAFETY: geteuid(2) has no preconditions.
    let root = unsafe { libc::geteuid() } == 0;
    let result = if root {
        Network::build()
    } else {
        Err("not running as root".into())
    };
    match result {
        Ok(n) => Some(n),
        Err(why) => {
            if std::env::var_os("PATHFARM_REQUIRE_NETNS").is_some_and(|v| v == "1") {
                panic!("PATHFARM_REQUIRE_NETNS=1 but network namespaces are unavailable: {why}");
            }
            eprintln!("SKIPPED: the network-namespace test needs root and `ip netns` ({why})");
            None
        }
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn worker_link_cut_mid_task_and_restored() {
    let Some(net) = network_or_skip() else {
        return;
    };
    let dir = TestDir::new("netns");
    let db = dir.arg("farm.db");
    let listen = format!("0.0.0.0:{PORT}");
    let in_ns = |role: &str| -> Vec<String> {
        ["ip", "netns", "exec"]
            .iter()
            .map(|s| s.to_string())
            .chain([net.ns(role)])
            .collect()
    };
    let srv_wrap = in_ns("srv");
    let srv_wrap: Vec<&str> = srv_wrap.iter().map(String::as_str).collect();
    let mut server = Proc::start_via(
        "server",
        &dir,
        &srv_wrap,
        &[
            "serve",
            "--listen",
            &listen,
            "--db",
            &db,
            "--lease-seconds",
            "3",
            // Listening beyond loopback requires tokens.
            "--client-token",
            CLIENT_TOKEN,
            "--worker-token",
            WORKER_TOKEN,
        ],
    );
    let server_addr: SocketAddr = format!("{}:{PORT}", net.addr(0, 2))
        .parse()
        .expect("server address");
    wait_healthy_at(server_addr, &mut server).await;
    let url = net.server_url();
    let api = ApiClient::new(&url, Some(CLIENT_TOKEN.into())).expect("API client");

    // Long enough that worker 1, cut off and marked lost, still finds work when it comes back:
    // at 1,024 spp worker 2 (which uploads while it renders) finished the job in the meantime.
    let settings = [
        "--width", "96", "--height", "96", "--spp", "4096", "--seed", "11",
    ];
    let mut submitted = settings.to_vec();
    submitted.extend_from_slice(&["--tile", "32", "--token", CLIENT_TOKEN]);
    let id = submit(&dir, &url, &submitted).await;
    let planned = 96 * 96 * 4096;
    let reference = render_reference(&dir, "local.exr", &settings);

    let worker = |k: u8| {
        let name = format!("worker-{k}");
        let wrap = in_ns(&format!("w{k}"));
        let wrap: Vec<&str> = wrap.iter().map(String::as_str).collect();
        let cache = dir.arg(&format!("cache-{k}"));
        Proc::start_via(
            &name,
            &dir,
            &wrap,
            &[
                "worker",
                "--server",
                &net.server_url_for_worker(k),
                "--threads",
                "1",
                "--slice-samples",
                "4",
                "--cache-dir",
                &cache,
                "--name",
                &name,
                "--token",
                WORKER_TOKEN,
            ],
        )
    };
    let w1 = worker(1);
    let w2 = worker(2);

    // Both hosts reach the server over their own link.
    poll(
        "both workers busy over the virtual network",
        Duration::from_secs(60),
        || async {
            let ws = workers(&api).await;
            let busy = |n: &str| {
                named(&ws, n).is_some_and(|w| w.state == WorkerState::Busy && w.samples_done > 0)
            };
            (busy("worker-1") && busy("worker-2")).then_some(())
        },
    )
    .await;

    // Cut worker 1's link while it holds a lease with slices merged and more to come.
    let at_cut = poll(
        "worker 1 in the middle of a task",
        Duration::from_secs(60),
        || async {
            let j = job(&api, &id).await;
            let ws = workers(&api).await;
            let w = named(&ws, "worker-1")?;
            let (_, left) = partial_tile(&j)?;
            (left >= 8 && w.current_task.is_some()).then_some(w.samples_done)
        },
    )
    .await;
    net.set_worker_link(1, false).expect("cut worker 1's link");
    let cut_job = job(&api, &id).await;
    assert!(
        !cut_job.state.is_final() && cut_job.samples_done < planned,
        "the job ended before the cut: {cut_job:?}"
    );

    // The server notices the silence: worker 1 is marked lost and its task goes back to the queue.
    poll("worker 1 marked lost", Duration::from_secs(30), || async {
        let ws = workers(&api).await;
        (named(&ws, "worker-1")?.state == WorkerState::Lost).then_some(())
    })
    .await;
    let during = named(&workers(&api).await, "worker-1")
        .expect("worker 1 listed")
        .samples_done;
    assert!(
        during >= at_cut,
        "worker 1's merged samples went down ({at_cut} → {during})"
    );

    net.set_worker_link(1, true)
        .expect("restore worker 1's link");
    // Worker 1 comes back and merges new work (the job is long enough to still have some).
    poll(
        "worker 1 to recover and merge new work",
        Duration::from_secs(90),
        || async {
            let ws = workers(&api).await;
            let w = named(&ws, "worker-1")?;
            (w.state != WorkerState::Lost && w.samples_done > during).then_some(())
        },
    )
    .await;

    let done = wait_completed(&api, &id, Duration::from_secs(240)).await;
    assert_eq!(done.samples_done, planned);
    assert_eq!(done.leased_tasks, 0);
    assert_merged_once_and_identical(
        &api,
        &id,
        planned,
        &["worker-1", "worker-2"],
        reference,
        "netns link cut",
    )
    .await;
    drop((w1, w2, server));
}
