//! A throw-away PostgreSQL server for the tests and the benchmark: Debian's server
//! binaries (/usr/lib/postgresql/*/bin), a new data directory in the temporary
//! directory, a free loopback port, stopped and removed when dropped. initdb and
//! postgres refuse to run as root: as root they run as the `postgres` user (or
//! `nobody`) through `runuser`, with a data directory that user owns.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

/// A running throw-away server.
pub struct TempPostgres {
    bin: PathBuf,
    dir: PathBuf,
    user: Option<String>,
    /// Its port on 127.0.0.1.
    pub port: u16,
}

/// The newest PostgreSQL server binaries' directory, if any.
pub fn server_bin() -> Option<PathBuf> {
    let mut dirs: Vec<PathBuf> = std::fs::read_dir("/usr/lib/postgresql")
        .ok()?
        .filter_map(|e| e.ok())
        .map(|e| e.path().join("bin"))
        .filter(|b| b.join("postgres").exists() && b.join("initdb").exists())
        .collect();
    dirs.sort_by_key(|d| {
        d.parent()
            .and_then(|p| p.file_name())
            .and_then(|n| n.to_str())
            .and_then(|n| n.parse::<u32>().ok())
            .unwrap_or(0)
    });
    dirs.pop()
}

fn is_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false)
}

fn user_exists(name: &str) -> bool {
    Command::new("id")
        .arg(name)
        .output()
        .map(|o| o.status.success())
        .unwrap_or(false)
}

impl TempPostgres {
    /// Starts a server, or says why it cannot: `Ok(None)` when no server binaries are
    /// installed (the caller skips), `Err` when they are but the server does not
    /// start.
    pub fn start(fsync: bool) -> Result<Option<TempPostgres>, String> {
        let Some(bin) = server_bin() else {
            return Ok(None);
        };
        let user = if is_root() {
            Some(
                ["postgres", "nobody"]
                    .into_iter()
                    .find(|u| user_exists(u))
                    .ok_or("running as root and neither user postgres nor nobody exists to run the server")?
                    .to_string(),
            )
        } else {
            None
        };
        static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
        let dir = std::env::temp_dir().join(format!(
            "hartkit-pg-{}-{}",
            std::process::id(),
            N.fetch_add(1, std::sync::atomic::Ordering::Relaxed)
        ));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("data")).map_err(|e| format!("{}: {e}", dir.display()))?;
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .and_then(|l| l.local_addr())
            .map_err(|e| format!("no free port: {e}"))?
            .port();
        let pg = TempPostgres {
            bin,
            dir,
            user,
            port,
        };
        if let Some(u) = &pg.user {
            let st = Command::new("chown")
                .args(["-R", u])
                .arg(&pg.dir)
                .status()
                .map_err(|e| format!("chown: {e}"))?;
            if !st.success() {
                return Err(format!("chown -R {u} {} failed", pg.dir.display()));
            }
        }
        let data = pg.dir.join("data");
        pg.run(
            "initdb",
            &[
                "-D",
                path(&data),
                "-U",
                "hartkit",
                "--auth=trust",
                "--encoding=UTF8",
                "--no-sync",
            ],
        )?;
        let mut conf = format!(
            "listen_addresses = '127.0.0.1'\nport = {port}\nunix_socket_directories = '{}'\nmax_wal_size = '1GB'\n",
            path(&pg.dir)
        );
        if !fsync {
            conf.push_str("fsync = off\nsynchronous_commit = off\nfull_page_writes = off\n");
        }
        std::fs::write(data.join("postgresql.auto.conf"), conf).map_err(|e| e.to_string())?;
        pg.start_again()?;
        Ok(Some(pg))
    }

    fn run(&self, tool: &str, args: &[&str]) -> Result<(), String> {
        let exe = self.bin.join(tool);
        let mut cmd = match &self.user {
            Some(u) => {
                let mut c = Command::new("runuser");
                c.args(["-u", u, "--"]).arg(&exe);
                c
            }
            None => Command::new(&exe),
        };
        let out = cmd
            .args(args)
            .current_dir(&self.dir)
            .output()
            .map_err(|e| format!("{tool}: {e}"))?;
        if !out.status.success() {
            return Err(format!(
                "{tool} {}: {}{}",
                args.join(" "),
                String::from_utf8_lossy(&out.stdout),
                String::from_utf8_lossy(&out.stderr)
            ));
        }
        Ok(())
    }

    /// The URL of its `postgres` database.
    pub fn url(&self) -> String {
        format!("postgres://hartkit@127.0.0.1:{}/postgres", self.port)
    }

    /// Stops the server (fast shutdown: sessions are cut).
    pub fn stop(&self) -> Result<(), String> {
        self.run(
            "pg_ctl",
            &[
                "-D",
                path(&self.dir.join("data")),
                "-m",
                "fast",
                "-w",
                "stop",
            ],
        )
    }

    /// Starts it again (same data, same port).
    pub fn start_again(&self) -> Result<(), String> {
        let log = self.dir.join("log");
        self.run(
            "pg_ctl",
            &[
                "-D",
                path(&self.dir.join("data")),
                "-l",
                path(&log),
                "-w",
                "-t",
                "60",
                "start",
            ],
        )
        .map_err(|e| {
            format!(
                "{e}\nserver log: {}",
                std::fs::read_to_string(&log).unwrap_or_default()
            )
        })?;
        let end = Instant::now() + Duration::from_secs(30);
        while std::net::TcpStream::connect(("127.0.0.1", self.port)).is_err() {
            if Instant::now() > end {
                return Err("the server does not listen".into());
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        Ok(())
    }
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap_or("")
}

impl Drop for TempPostgres {
    fn drop(&mut self) {
        let _ = self.run(
            "pg_ctl",
            &[
                "-D",
                path(&self.dir.join("data")),
                "-m",
                "immediate",
                "-w",
                "stop",
            ],
        );
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// A server for a test, or `None` with the reason printed when PostgreSQL is not
/// installed (unless `HARTKIT_REQUIRE_INTEROP=1`, when that fails the test).
pub fn for_test(fsync: bool) -> Option<TempPostgres> {
    match TempPostgres::start(fsync) {
        Ok(Some(pg)) => Some(pg),
        Ok(None) => {
            if std::env::var("HARTKIT_REQUIRE_INTEROP").as_deref() == Ok("1") {
                panic!("HARTKIT_REQUIRE_INTEROP=1 and no PostgreSQL server under /usr/lib/postgresql/*/bin (apt-get install postgresql)");
            }
            eprintln!("skipped: no PostgreSQL server under /usr/lib/postgresql/*/bin (apt-get install postgresql)");
            None
        }
        Err(e) => panic!("PostgreSQL is installed but did not start: {e}"),
    }
}
