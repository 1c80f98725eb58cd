//! Slow clients against a running server, for issue 32's figure "connections held by a slow
//! client" (`docs/benchmarks.md`).
//!
//! ```text
//! cargo run -p pathfarm-server --example slow_clients -- stall 127.0.0.1:8080 2000 5,12,25,75
//! cargo run -p pathfarm-server --example slow_clients -- bogus-uploads 127.0.0.1:8080 3 100 1
//! ```
//!
//! `stall ADDR N SECONDS,…`: opens N connections, each sends half a request header and stalls;
//! at each checkpoint it prints how many the server still holds open (neither closed nor reset).
//! `bogus-uploads ADDR N MIB TASK`: N concurrent slice uploads of MIB MiB each to task TASK with
//! a lease token that does not hold it; prints each answer's status line and when it came.

use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

#[tokio::main]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.iter().map(String::as_str).collect::<Vec<_>>()[..] {
        ["stall", addr, n, checkpoints] => {
            let checkpoints = checkpoints
                .split(',')
                .map(str::parse::<f64>)
                .collect::<Result<Vec<_>, _>>()?;
            stall(addr, n.parse()?, &checkpoints).await
        }
        ["bogus-uploads", addr, n, mib, task] => {
            bogus_uploads(addr, n.parse()?, mib.parse()?, task.parse()?).await
        }
        _ => {
            Err("usage: slow_clients stall ADDR N SECONDS,… | bogus-uploads ADDR N MIB TASK".into())
        }
    }
}

async fn stall(
    addr: &str,
    n: usize,
    checkpoints: &[f64],
) -> Result<(), Box<dyn std::error::Error>> {
    let started = Instant::now();
    let mut streams = Vec::with_capacity(n);
    for _ in 0..n {
        // Beyond the server's cap (and its listen backlog) a connect may wait: do not let one
        // hold up the rest.
        let s = TcpStream::connect(addr).await?;
        let mut s = s;
        s.write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            .await?;
        streams.push(Some(s));
    }
    println!(
        "opened {n} stalled connections in {:.1} s",
        started.elapsed().as_secs_f64()
    );
    for &at in checkpoints {
        let when = started + Duration::from_secs_f64(at);
        tokio::time::sleep_until(when.into()).await;
        let mut buf = [0u8; 1024];
        for slot in streams.iter_mut() {
            let Some(s) = slot else { continue };
            let closed = match s.try_read(&mut buf) {
                Ok(0) => true,
                Ok(_) => false, // an answer, but the connection is still open
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => false,
                Err(_) => true,
            };
            if closed {
                *slot = None;
            }
        }
        let open = streams.iter().filter(|s| s.is_some()).count();
        println!("after {at:>5.1} s: the server holds {open} of {n}");
    }
    Ok(())
}

async fn bogus_uploads(
    addr: &str,
    n: usize,
    mib: usize,
    task: i64,
) -> Result<(), Box<dyn std::error::Error>> {
    let started = Instant::now();
    let mut uploads = Vec::new();
    for i in 0..n {
        let addr = addr.to_string();
        uploads.push(tokio::spawn(async move {
            let len = mib << 20;
            let mut s = TcpStream::connect(&addr).await?;
            let head = format!(
                "POST /api/v1/tasks/{task}/slices HTTP/1.1\r\nHost: {addr}\r\n\
                 Content-Type: application/x-pathfarm-slice\r\nPathfarm-Lease-Token: bogus-{i}\r\n\
                 Content-Length: {len}\r\n\r\n"
            );
            s.write_all(head.as_bytes()).await?;
            let (mut rd, mut wr) = s.into_split();
            let body = tokio::spawn(async move {
                let chunk = vec![0u8; 1 << 20];
                let mut sent = 0usize;
                while sent < len {
                    if wr.write_all(&chunk).await.is_err() {
                        break;
                    }
                    sent += chunk.len();
                }
                sent
            });
            let mut answer = vec![0u8; 512];
            let got = rd.read(&mut answer).await.unwrap_or(0);
            let at = started.elapsed().as_secs_f64();
            body.abort();
            let line = String::from_utf8_lossy(&answer[..got])
                .lines()
                .next()
                .unwrap_or("(closed without an answer)")
                .to_string();
            Ok::<_, std::io::Error>((line, at))
        }));
    }
    for (i, u) in uploads.into_iter().enumerate() {
        let (line, at) = u.await??;
        println!("upload {i}: {line} after {at:.2} s");
    }
    Ok(())
}
