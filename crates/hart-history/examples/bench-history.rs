//! The historian's benchmark, the same code as `hartkit history bench`: inserts
//! DEVICES x 7 variables once a second for SECONDS through the writer, then times
//! `hartkit history query`'s code on one day of one variable at 1 s resolution.
//!
//! Usage: bench-history DB [DEVICES [SECONDS [REPEAT]]]

fn main() {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let Some(db) = a.first() else {
        eprintln!("usage: bench-history DB [DEVICES [SECONDS [REPEAT]]]");
        std::process::exit(2);
    };
    let num = |i: usize, d: u64| a.get(i).and_then(|s| s.parse().ok()).unwrap_or(d);
    let args = hart_history::bench::BenchArgs {
        db: db.clone(),
        devices: num(1, 2) as usize,
        seconds: num(2, 86_400),
        repeat: num(3, 5) as usize,
    };
    match hart_history::bench::run(&args) {
        Ok(r) => println!("{r}"),
        Err(e) => {
            eprintln!("bench-history: {e}");
            std::process::exit(5);
        }
    }
}
