//! Starts a throw-away PostgreSQL server (as the tests do), prints its URL, and
//! stops it when standard input closes: for scripts/bench-history.
//!
//! Usage: temp-postgres [--fsync]

use std::io::{Read, Write};

fn main() {
    let fsync = std::env::args().any(|a| a == "--fsync");
    match hart_history::pgtest::TempPostgres::start(fsync) {
        Ok(Some(pg)) => {
            println!("{}", pg.url());
            let _ = std::io::stdout().flush();
            let mut sink = vec![];
            let _ = std::io::stdin().read_to_end(&mut sink);
            drop(pg);
        }
        Ok(None) => {
            eprintln!("temp-postgres: no PostgreSQL server under /usr/lib/postgresql/*/bin (apt-get install postgresql)");
            std::process::exit(3);
        }
        Err(e) => {
            eprintln!("temp-postgres: {e}");
            std::process::exit(5);
        }
    }
}
