//! A private PostgreSQL cluster owned by this process: the embedded default database.
//!
//! With no `DATABASE_URL`, the server keeps its own cluster under its data folder. The cluster is
//! created with the system's `initdb`, and its postmaster runs as a child process that cannot
//! outlive us:
//!
//! - it listens on a unix socket only (`listen_addresses = ''`), in a directory only its owner
//!   can open, and `pg_hba.conf` allows `trust` on that socket and nothing else;
//! - it is started in its own process group (a terminal's Ctrl-C reaches the server, which then
//!   shuts the database down in order) with a parent-death signal, so even a `SIGKILL`ed server
//!   takes its database down (PostgreSQL's fast shutdown, which is crash safe);
//! - when the process runs as root (PostgreSQL refuses to), `initdb` and `postgres` run as an
//!   unprivileged account (`postgres` by default, `PAINSIM_PG_USER` to override), which owns the
//!   cluster directory.
//!
//! The same helper gives every test its own database (`test_support`, compiled only with the
//! `test-support` feature).

use std::fs;
use std::io::{Read, Seek, SeekFrom};
use std::os::unix::fs::{PermissionsExt, chown};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Mutex, mpsc};
use std::time::{Duration, Instant};

use sqlx::postgres::PgConnectOptions;
use thiserror::Error;

/// Superuser role created by `initdb -U`; fixed so URLs do not depend on who ran it.
pub const SUPERUSER: &str = "postgres";

/// Longest unix socket path PostgreSQL accepts is `sizeof(sun_path) - 1` = 107 bytes on Linux;
/// the socket file name `.s.PGSQL.5432` takes 13 of them plus a slash.
const MAX_SOCKET_DIR_LEN: usize = 107 - 14;

/// How long the postmaster gets to become ready. A cold `initdb` is done before this starts;
/// crash recovery of a small cluster takes well under a second, so 60 s is generous.
const READY_TIMEOUT: Duration = Duration::from_secs(60);

/// Why the private cluster could not be started or stopped.
#[derive(Debug, Error)]
pub enum EmbeddedPgError {
    /// A PostgreSQL server binary is missing.
    #[error(
        "PostgreSQL server binary `{binary}` not found on PATH or under /usr/lib/postgresql/*/bin. \
         Install it (Debian/Ubuntu: `apt-get install postgresql`), or set DATABASE_URL to use an \
         existing server instead of the embedded one"
    )]
    MissingBinary {
        /// `initdb` or `postgres`.
        binary: &'static str,
    },
    /// Running as root but the unprivileged account does not exist.
    #[error(
        "running as root, but PostgreSQL refuses to run as root and the account `{0}` does not exist; \
         create it (`adduser --system {0}`; Debian's postgresql package does this) or set PAINSIM_PG_USER"
    )]
    NoUnprivilegedUser(String),
    /// `initdb` failed.
    #[error("initdb failed for {dir}: {output}{hint}")]
    Initdb {
        /// The data directory.
        dir: PathBuf,
        /// What initdb printed.
        output: String,
        /// A suggestion, when the failure has a known cause.
        hint: String,
    },
    /// The postmaster exited or did not become ready.
    #[error("the private PostgreSQL cluster in {dir} did not start: {reason}\n--- last lines of {log} ---\n{log_tail}")]
    Start {
        /// The data directory.
        dir: PathBuf,
        /// What went wrong.
        reason: String,
        /// The server log file.
        log: PathBuf,
        /// Its last lines.
        log_tail: String,
    },
    /// Running as root, the unprivileged account cannot reach the data folder.
    #[error(
        "the PostgreSQL account (uid {uid}) cannot enter {dir}, a parent of the data folder; choose a \
         data folder it can reach (PAINSIM_DATA_DIR, e.g. under /var/lib or /tmp) or allow it with `chmod o+x {dir}`"
    )]
    NotReachable {
        /// The directory that blocks the way.
        dir: PathBuf,
        /// The unprivileged account's uid.
        uid: u32,
    },
    /// A file system operation failed.
    #[error("{context}: {source}")]
    Io {
        /// What was being done.
        context: String,
        /// The OS error.
        source: std::io::Error,
    },
}

fn io_err(context: impl Into<String>) -> impl FnOnce(std::io::Error) -> EmbeddedPgError {
    let context = context.into();
    move |source| EmbeddedPgError::Io { context, source }
}

/// The PostgreSQL server programs this module needs.
#[derive(Debug, Clone)]
pub struct PgBinaries {
    /// `initdb`.
    pub initdb: PathBuf,
    /// `postgres` (the postmaster).
    pub postgres: PathBuf,
}

impl PgBinaries {
    /// Finds `initdb` and `postgres` on `PATH`, then under Debian's `/usr/lib/postgresql/<major>/bin`
    /// (newest major first), where the server binaries live without being on `PATH`.
    pub fn locate() -> Result<PgBinaries, EmbeddedPgError> {
        let mut dirs: Vec<PathBuf> = std::env::var_os("PATH").map(|p| std::env::split_paths(&p).collect()).unwrap_or_default();
        if let Ok(entries) = fs::read_dir("/usr/lib/postgresql") {
            let mut majors: Vec<(u32, PathBuf)> = entries
                .filter_map(|e| e.ok())
                .filter_map(|e| Some((e.file_name().to_str()?.parse::<u32>().ok()?, e.path().join("bin"))))
                .collect();
            majors.sort_by_key(|m| std::cmp::Reverse(m.0));
            dirs.extend(majors.into_iter().map(|(_, p)| p));
        }
        Self::locate_in(&dirs)
    }

    /// Finds the binaries in `dirs`, in order.
    pub fn locate_in(dirs: &[PathBuf]) -> Result<PgBinaries, EmbeddedPgError> {
        let find = |binary: &'static str| {
            dirs.iter()
                .map(|d| d.join(binary))
                .find(|p| p.metadata().is_ok_and(|m| m.is_file() && m.permissions().mode() & 0o111 != 0))
                .ok_or(EmbeddedPgError::MissingBinary { binary })
        };
        Ok(PgBinaries { initdb: find("initdb")?, postgres: find("postgres")? })
    }
}

/// The account the cluster runs as.
#[derive(Debug, Clone, Copy)]
struct RunAs {
    uid: u32,
    gid: u32,
}

fn is_root() -> bool {
    // `/proc/self` is owned by the process's effective uid.
    fs::metadata("/proc/self").map(|m| std::os::unix::fs::MetadataExt::uid(&m) == 0).unwrap_or(false)
}

/// When root, the unprivileged account from `/etc/passwd`; otherwise run as ourselves.
fn run_as() -> Result<Option<RunAs>, EmbeddedPgError> {
    if !is_root() {
        return Ok(None);
    }
    let user = crate::config::embedded_pg_user(crate::config::env);
    let passwd = fs::read_to_string("/etc/passwd").map_err(io_err("reading /etc/passwd"))?;
    passwd
        .lines()
        .map(|l| l.split(':').collect::<Vec<_>>())
        .find(|f| f.len() > 3 && f[0] == user)
        .and_then(|f| Some(RunAs { uid: f[2].parse().ok()?, gid: f[3].parse().ok()? }))
        .map(Some)
        .ok_or(EmbeddedPgError::NoUnprivilegedUser(user))
}

/// Every ancestor of `dir` must be searchable (`x`) by the account, or PostgreSQL cannot open
/// its own files (initdb then fails with a confusing "No such file or directory").
fn check_reachable(dir: &Path, o: RunAs) -> Result<(), EmbeddedPgError> {
    use std::os::unix::fs::MetadataExt;
    for ancestor in dir.ancestors().skip(1) {
        let Ok(m) = fs::metadata(ancestor) else { continue };
        let mode = m.mode();
        let searchable = if m.uid() == o.uid {
            mode & 0o100 != 0
        } else if m.gid() == o.gid {
            mode & 0o010 != 0
        } else {
            mode & 0o001 != 0
        };
        if !searchable {
            return Err(EmbeddedPgError::NotReachable { dir: ancestor.to_owned(), uid: o.uid });
        }
    }
    Ok(())
}

/// Creates `dir` (mode 0700) owned by the account the cluster runs as.
fn private_dir(dir: &Path, owner: Option<RunAs>) -> Result<(), EmbeddedPgError> {
    fs::create_dir_all(dir).map_err(io_err(format!("creating {}", dir.display())))?;
    if let Some(o) = owner {
        chown(dir, Some(o.uid), Some(o.gid)).map_err(io_err(format!("chown {}", dir.display())))?;
    }
    fs::set_permissions(dir, fs::Permissions::from_mode(0o700)).map_err(io_err(format!("chmod {}", dir.display())))
}

/// A running private cluster. Dropping it does not stop it; call [`PrivateCluster::stop`].
/// If the process dies first, the kernel's parent-death signal stops it.
#[derive(Debug)]
pub struct PrivateCluster {
    data_dir: PathBuf,
    socket_dir: PathBuf,
    log_path: PathBuf,
    pid: u32,
    exited: Mutex<mpsc::Receiver<std::io::Result<std::process::ExitStatus>>>,
}

impl PrivateCluster {
    /// Starts (creating on first use) the cluster under `root` (`root/data`, `root/socket`,
    /// `root/postgres.log`) and waits until it accepts connections.
    pub fn start(root: &Path) -> Result<PrivateCluster, EmbeddedPgError> {
        let bins = PgBinaries::locate()?;
        let owner = run_as()?;
        fs::create_dir_all(root).map_err(io_err(format!("creating {}", root.display())))?;
        let root = root.canonicalize().map_err(io_err(format!("resolving {}", root.display())))?;
        if let Some(o) = owner {
            check_reachable(&root, o)?;
        }
        private_dir(&root, owner)?;
        let data_dir = root.join("data");
        let log_path = root.join("postgres.log");
        let socket_dir = {
            let preferred = root.join("socket");
            if preferred.as_os_str().len() <= MAX_SOCKET_DIR_LEN {
                preferred
            } else {
                // Deep data folders overflow sun_path; use a short private directory instead.
                let h = root.to_string_lossy().bytes().fold(0xcbf29ce484222325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100000001b3));
                std::env::temp_dir().join(format!("painsim-pg-{h:016x}"))
            }
        };
        private_dir(&socket_dir, owner)?;

        if !data_dir.join("PG_VERSION").exists() {
            initdb(&bins, &data_dir, owner)?;
        }
        wait_for_previous_postmaster(&data_dir)?;

        let log = fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&log_path)
            .map_err(io_err(format!("opening {}", log_path.display())))?;
        let log_start = log.metadata().map(|m| m.len()).unwrap_or(0);
        let mut cmd = Command::new(&bins.postgres);
        cmd.arg("-D")
            .arg(&data_dir)
            .arg("-k")
            .arg(&socket_dir)
            .args(["-c", "listen_addresses=", "-c", "unix_socket_permissions=0700", "-p", "5432"])
            // Small, predictable footprint: a training platform needs few connections.
            .args(["-c", "max_connections=200", "-c", "shared_buffers=64MB"])
            .stdin(Stdio::null())
            .stdout(log.try_clone().map_err(io_err("duplicating log handle"))?)
            .stderr(log)
            .process_group(0);
        if let Some(o) = owner {
            cmd.uid(o.uid).gid(o.gid);
        }
        set_parent_death_signal(&mut cmd);

        // The postmaster is spawned by, and waited on from, a thread that lives as long as the
        // process: the parent-death signal fires when the *spawning thread* exits, so it must
        // not be a short-lived runtime or test thread.
        let (spawned_tx, spawned_rx) = mpsc::channel();
        let (exit_tx, exit_rx) = mpsc::channel();
        std::thread::Builder::new()
            .name("postgres-keeper".into())
            .spawn(move || match cmd.spawn() {
                Ok(mut child) => {
                    let _ = spawned_tx.send(Ok(child.id()));
                    let _ = exit_tx.send(child.wait());
                }
                Err(e) => {
                    let _ = spawned_tx.send(Err(e));
                }
            })
            .map_err(io_err("spawning the postgres keeper thread"))?;
        let pid = spawned_rx
            .recv()
            .map_err(|e| EmbeddedPgError::Io { context: "postgres keeper thread".into(), source: std::io::Error::other(e) })?
            .map_err(io_err(format!("starting {}", bins.postgres.display())))?;

        let cluster = PrivateCluster { data_dir, socket_dir, log_path, pid, exited: Mutex::new(exit_rx) };
        cluster.wait_until_ready(log_start)?;
        tracing::info!(pid, data = %cluster.data_dir.display(), socket = %cluster.socket_dir.display(), "private PostgreSQL cluster ready");
        Ok(cluster)
    }

    /// Polls `postmaster.pid` until its status line says `ready` (what `pg_ctl -w` does).
    fn wait_until_ready(&self, log_start: u64) -> Result<(), EmbeddedPgError> {
        let deadline = Instant::now() + READY_TIMEOUT;
        loop {
            if let Ok(status) = self.exited.lock().unwrap_or_else(|p| p.into_inner()).try_recv() {
                return Err(self.start_error(format!("postgres exited during start-up ({status:?})"), log_start));
            }
            if let Ok(text) = fs::read_to_string(self.data_dir.join("postmaster.pid")) {
                let lines: Vec<&str> = text.lines().collect();
                // Line 1 is the pid, line 8 the status ("starting", "ready", "stopping").
                if lines.first().map(|l| l.trim()) == Some(self.pid.to_string().as_str()) && lines.get(7).is_some_and(|s| s.trim() == "ready") {
                    return Ok(());
                }
            }
            if Instant::now() > deadline {
                return Err(self.start_error(format!("not ready after {READY_TIMEOUT:?}"), log_start));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn start_error(&self, reason: String, log_start: u64) -> EmbeddedPgError {
        EmbeddedPgError::Start {
            dir: self.data_dir.clone(),
            reason,
            log: self.log_path.clone(),
            log_tail: tail_of(&self.log_path, log_start),
        }
    }

    /// Connection options for `database` over the private socket.
    pub fn connect_options(&self, database: &str) -> PgConnectOptions {
        PgConnectOptions::new().socket(&self.socket_dir).port(5432).username(SUPERUSER).database(database)
    }

    /// A `postgres://` URL for `database` that other processes (and sqlx) can use.
    pub fn url(&self, database: &str) -> String {
        let host: String = self
            .socket_dir
            .to_string_lossy()
            .bytes()
            .map(|b| if b.is_ascii_alphanumeric() || b"-._~".contains(&b) { (b as char).to_string() } else { format!("%{b:02X}") })
            .collect();
        format!("postgres://{SUPERUSER}@localhost:5432/{database}?host={host}")
    }

    /// Process id of the postmaster.
    pub fn pid(&self) -> u32 {
        self.pid
    }

    /// The cluster's data directory.
    pub fn data_dir(&self) -> &Path {
        &self.data_dir
    }

    /// Fast shutdown (`SIGINT`, as `pg_ctl stop -m fast`): open sessions are ended, everything
    /// committed is flushed, and this waits until the postmaster has exited.
    pub fn stop(self) -> Result<(), EmbeddedPgError> {
        send_signal(self.pid, libc::SIGINT);
        let outcome = self.exited.lock().unwrap_or_else(|p| p.into_inner()).recv_timeout(Duration::from_secs(60));
        match outcome {
            Ok(_) => {
                tracing::info!(pid = self.pid, "private PostgreSQL cluster stopped");
                Ok(())
            }
            Err(_) => {
                send_signal(self.pid, libc::SIGQUIT);
                Err(EmbeddedPgError::Start {
                    dir: self.data_dir.clone(),
                    reason: "did not stop within 60 s after SIGINT; sent SIGQUIT".into(),
                    log: self.log_path.clone(),
                    log_tail: tail_of(&self.log_path, 0),
                })
            }
        }
    }
}

fn initdb(bins: &PgBinaries, data_dir: &Path, owner: Option<RunAs>) -> Result<(), EmbeddedPgError> {
    tracing::info!(dir = %data_dir.display(), "creating private PostgreSQL cluster (first start)");
    // initdb builds into a scratch directory that is renamed into place only when complete, so an
    // interrupted first start never leaves a half-made cluster behind.
    let scratch = data_dir.with_extension("initdb-tmp");
    let _ = fs::remove_dir_all(&scratch);
    let mut cmd = Command::new(&bins.initdb);
    cmd.arg("-D")
        .arg(&scratch)
        .args(["-U", SUPERUSER, "--auth=trust", "--encoding=UTF8", "--locale=C", "--no-instructions"])
        .stdin(Stdio::null());
    if let Some(o) = owner {
        cmd.uid(o.uid).gid(o.gid);
    }
    let out = cmd.output().map_err(io_err(format!("running {}", bins.initdb.display())))?;
    if !out.status.success() {
        let output = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        let hint = if output.contains("ermission denied") {
            "\nhint: the PostgreSQL account must be able to reach this folder; when running as root, \
             choose a data folder outside /root (PAINSIM_DATA_DIR)"
                .to_owned()
        } else {
            String::new()
        };
        return Err(EmbeddedPgError::Initdb { dir: data_dir.to_owned(), output, hint });
    }
    // Only the private socket is trusted: no TCP entries at all.
    fs::write(
        scratch.join("pg_hba.conf"),
        "# Written by pain-sim: the cluster listens on a private unix socket only.\n\
         # TYPE  DATABASE  USER  METHOD\n\
         local   all       all   trust\n",
    )
    .map_err(io_err("writing pg_hba.conf"))?;
    fs::rename(&scratch, data_dir).map_err(io_err(format!("moving the new cluster to {}", data_dir.display())))
}

/// How long orphaned processes of a killed postmaster (its backends and auxiliary processes, which
/// notice their parent's death on their own within about a second) get before they are killed.
/// Our choice: well above that, well below a start-up a person would give up on.
const ORPHAN_GRACE: Duration = Duration::from_secs(5);

/// The processes running in `data_dir` (every postgres process of a cluster, the postmaster, its
/// backends and auxiliary processes, has the data folder as its working directory).
fn cluster_processes(data_dir: &Path) -> Vec<u32> {
    let Ok(dir) = data_dir.canonicalize() else { return Vec::new() };
    let me = std::process::id();
    let Ok(entries) = fs::read_dir("/proc") else { return Vec::new() };
    entries
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
        .filter(|&pid| pid != me)
        .filter(|pid| fs::read_link(format!("/proc/{pid}/cwd")).is_ok_and(|cwd| cwd == dir))
        .filter(|pid| fs::read(format!("/proc/{pid}/cmdline")).is_ok_and(|c| c.windows(8).any(|w| w == b"postgres")))
        .collect()
}

/// Makes the data folder startable after a previous run ended badly: waits for a postmaster that
/// is still shutting down; when the postmaster is gone but processes of its cluster linger (a
/// SIGKILL of the postmaster, or of the server and PostgreSQL together, orphans its backends,
/// which keep the shared memory attached and make postgres refuse to start), kills them after
/// [`ORPHAN_GRACE`]; and removes a `postmaster.pid` whose process is gone, since postgres itself
/// refuses one whose pid now belongs to another live process.
fn wait_for_previous_postmaster(data_dir: &Path) -> Result<(), EmbeddedPgError> {
    let pid_file = data_dir.join("postmaster.pid");
    let started = Instant::now();
    let deadline = started + Duration::from_secs(30);
    loop {
        let recorded = fs::read_to_string(&pid_file).ok().and_then(|t| t.lines().next()?.trim().parse::<u32>().ok());
        let left = cluster_processes(data_dir);
        if left.is_empty() {
            if recorded.is_some() {
                tracing::warn!(data = %data_dir.display(), "removing the lock file of a postmaster that was killed");
                fs::remove_file(&pid_file).map_err(io_err(format!("removing the stale {}", pid_file.display())))?;
            }
            return Ok(());
        }
        let postmaster_alive = recorded.is_some_and(|pid| left.contains(&pid));
        if !postmaster_alive && started.elapsed() >= ORPHAN_GRACE {
            tracing::warn!(data = %data_dir.display(), orphans = ?left, "killing processes left behind by a killed postmaster");
            for pid in &left {
                send_signal(*pid, libc::SIGKILL);
            }
        }
        if Instant::now() > deadline {
            return Err(EmbeddedPgError::Start {
                dir: data_dir.to_owned(),
                reason: match recorded {
                    Some(pid) if postmaster_alive => format!("another postgres (pid {pid}) is still running on this data folder"),
                    _ => format!("processes of a previous cluster ({left:?}) are still running on this data folder"),
                },
                log: data_dir.join("../postgres.log"),
                log_tail: String::new(),
            });
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

fn tail_of(path: &Path, from: u64) -> String {
    let mut text = String::new();
    if let Ok(mut f) = fs::File::open(path) {
        let len = f.metadata().map(|m| m.len()).unwrap_or(0);
        let start = from.max(len.saturating_sub(4096));
        let _ = f.seek(SeekFrom::Start(start));
        let _ = f.read_to_string(&mut text);
    }
    text.lines().rev().take(20).collect::<Vec<_>>().into_iter().rev().collect::<Vec<_>>().join("\n")
}

#[expect(unsafe_code, reason = "prctl in the forked child is the only way to tie the postmaster's life to ours")]
fn set_parent_death_signal(cmd: &mut Command) {
    // SAFETY: the closure runs in the child between fork and exec and only calls prctl(2) and
    // getppid(2), both async-signal-safe. If our process already died between fork and prctl,
    // the child's parent has changed, and we exit at once rather than run unsupervised.
    unsafe {
        cmd.pre_exec(|| {
            let parent = libc::getppid();
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGINT) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            if libc::getppid() != parent || parent == 1 {
                libc::_exit(1);
            }
            Ok(())
        });
    }
}

#[expect(unsafe_code, reason = "kill(2) has no safe wrapper in std")]
fn send_signal(pid: u32, signal: libc::c_int) {
    // SAFETY: kill(2) on a pid we spawned and still wait on (it cannot have been reused), or on a
    // process just seen running postgres in our private data folder.
    unsafe {
        libc::kill(pid as libc::pid_t, signal);
    }
}
