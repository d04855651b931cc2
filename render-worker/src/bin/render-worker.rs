//! The `render-worker` process: opens the GPU, proves it with a compute self-test, and reports
//! its health at `GET /healthz` on `RENDER_WORKER_BIND` (default `127.0.0.1:8081`).
//!
//! In the embedded default the server runs its worker in-process and this binary is not needed;
//! it is the unit that scales out (see docker-compose.yml). Session hosting over websockets and
//! registration with the server build on this process.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::process::ExitCode;

use render_worker::gpu::{GpuContext, saxpy};

fn main() -> ExitCode {
    let bind = std::env::var("RENDER_WORKER_BIND").unwrap_or_else(|_| "127.0.0.1:8081".to_owned());
    let ctx = match GpuContext::new_headless() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("render-worker: {e}");
            return ExitCode::FAILURE;
        }
    };
    let x: Vec<f32> = (0..256).map(|i| i as f32).collect();
    let ok = saxpy(&ctx, 2.0, &x, 1.0).is_ok_and(|y| y.iter().zip(&x).all(|(y, x)| *y == 2.0 * x + 1.0));
    if !ok {
        eprintln!("render-worker: GPU self-test failed on {}", ctx.summary.name);
        return ExitCode::FAILURE;
    }
    let health = serde_json::json!({ "status": "ok", "adapter": ctx.summary, "capacity_sessions": 8 }).to_string();
    let listener = match TcpListener::bind(&bind) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("render-worker: cannot bind {bind}: {e}");
            return ExitCode::FAILURE;
        }
    };
    println!("render-worker on {} ready at http://{}/healthz", ctx.summary.name, listener.local_addr().map(|a| a.to_string()).unwrap_or(bind));
    for stream in listener.incoming().flatten() {
        let mut reader = BufReader::new(&stream);
        let mut request_line = String::new();
        if reader.read_line(&mut request_line).is_err() {
            continue;
        }
        let (status, body) = if request_line.starts_with("GET /healthz ") {
            ("200 OK", health.as_str())
        } else {
            ("404 Not Found", r#"{"error":{"code":"not_found","message":"only GET /healthz is served"}}"#)
        };
        let mut stream = &stream;
        let _ = write!(
            stream,
            "HTTP/1.1 {status}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            body.len()
        );
    }
    ExitCode::SUCCESS
}
