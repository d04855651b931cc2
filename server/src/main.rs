//! The `server` binary: `server` (or `server serve`) runs the platform.

use std::process::ExitCode;

fn main() -> ExitCode {
    render_worker::alloc::limit_malloc_arenas();
    server::telemetry::init();
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.first().map(String::as_str) {
        None | Some("serve") => {}
        Some("create-admin") => return server::cli::create_admin_main(&args[1..]),
        Some("-h" | "--help" | "help") => {
            println!("usage: server [serve | create-admin --email ADDRESS]\n\nConfiguration comes from the environment; see server/src/config.rs.");
            return ExitCode::SUCCESS;
        }
        Some(other) => {
            eprintln!("unknown command {other:?}; try `server --help`");
            return ExitCode::from(2);
        }
    }
    let config = match server::Config::from_env() {
        Ok(c) => c,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let runtime = tokio::runtime::Builder::new_multi_thread().enable_all().build().expect("building the tokio runtime");
    let outcome = runtime.block_on(server::startup::run(config));
    // The database is stopped by now; a blocking task still running (a replay, an anatomy build)
    // holds nothing that must be saved, so it must not hold the exit either.
    runtime.shutdown_timeout(std::time::Duration::from_secs(2));
    let code = match outcome {
        Ok(()) => 0,
        Err(e) => {
            eprintln!("error: {e:#}");
            1
        }
    };
    // Everything that must be kept is stored and the database stopped: leave without the C
    // library's exit handlers, which race with driver work still running on other threads.
    render_worker::exit::after_shutdown(code)
}
