//! The gateway's PROFIBUS DP front end against an outside master: pyprofibus
//! (GPL-2.0-or-later), run as a separate process by `scripts/interop/pyprofibus_master.py`,
//! configured from the GSD file `hartkit serve --print-gsd` writes, over a socat
//! pseudo-terminal pair at 19.2 kbit/s. It parameterises and configures the station,
//! reaches data exchange, reads each device's PV in its units and changing, and makes a
//! loop-test write that lands on the device. pyprofibus's GSD parser reads the file.
//!
//! Without the interop venv (`scripts/interop/setup`) the checks say so and pass,
//! unless `HARTKIT_REQUIRE_INTEROP=1`. The printed map and GSD are checked always.

use std::path::PathBuf;

mod common;
use common::{gateway, hartkit, pty_pair};

fn python() -> Option<PathBuf> {
    common::interop_python("pyprofibus")
}

/// A directory with the GSD file, a plant (a pressure transmitter at polling address
/// 0, which drives its loop current, and a temperature transmitter at 1) and a
/// gateway configuration with that plant's loop.
fn files(test: &str) -> (PathBuf, PathBuf, PathBuf) {
    let dir = std::env::temp_dir().join(format!("hartkit-pb-{}-{test}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (code, gsd, err) = hartkit(&["serve", "--print-gsd"]);
    assert_eq!(code, 0, "{err}");
    let gsd_path = dir.join("hartkit.gsd");
    std::fs::write(&gsd_path, gsd).unwrap();
    let plant = dir.join("plant.toml");
    std::fs::write(
        &plant,
        "[[device]]\nprofile = \"pressure\"\npoll = 0\n\n[[device]]\nprofile = \"temperature\"\npoll = 1\n",
    )
    .unwrap();
    let config = dir.join("gateway.toml");
    std::fs::write(
        &config,
        format!(
            "[[loop]]\nport = \"sim:{}\"\nscan_to = 2\n",
            plant.display()
        ),
    )
    .unwrap();
    (dir, gsd_path, config)
}

#[test]
fn the_printed_map_and_gsd() {
    let (code, map, err) = hartkit(&["serve", "--sim", "--instant", "--print-map", "--profibus"]);
    assert_eq!(code, 0, "{err}");
    assert!(
        map.contains("station 5: 4 modules, 112 input bytes, 24 output bytes"),
        "{map}"
    );
    assert!(
        map.contains("module 2 (slot 1): device 1 TT-200: inputs 28..55, outputs 6..11"),
        "{map}"
    );
    let (code, map, _) = hartkit(&[
        "serve",
        "--sim",
        "--instant",
        "--print-map",
        "--profibus",
        "--profibus-address",
        "9",
    ]);
    assert_eq!(code, 0);
    assert!(map.contains("station 9:"), "{map}");
    let (code, gsd, _) = hartkit(&["serve", "--print-gsd"]);
    assert_eq!(code, 0);
    assert!(gsd.contains("Ident_Number=0x4854"), "{gsd}");
    let (code, _, err) = hartkit(&[
        "serve",
        "--sim",
        "--profibus",
        "/dev/null",
        "--profibus-baud",
        "12345",
    ]);
    assert_eq!(code, 2);
    assert!(err.contains("9600, 19200, 45450 or 93750"), "{err}");
    let (code, _, err) = hartkit(&["serve", "--sim", "--profibus"]);
    assert_eq!(code, 2);
    assert!(err.contains("needs a serial port"), "{err}");
}

#[test]
fn pyprofibus_reads_the_gsd_file() {
    let Some(py) = python() else { return };
    let (dir, gsd, _) = files("gsd");
    let out = std::process::Command::new(py.parent().unwrap().join("gsdparser"))
        .args(["-S", gsd.to_str().unwrap()])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("hartkit HART gateway"), "{text}");
    assert!(text.contains("Ident 0x4854"), "{text}");
    assert!(text.contains("\"HART device 28 in/6 out\""), "{text}");
    let _ = std::fs::remove_dir_all(dir);
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn hex(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap())
        .collect()
}

#[test]
fn pyprofibus_master_exchanges_data_and_makes_a_loop_test() {
    let Some(py) = python() else { return };
    let Some(pty) = pty_pair() else { return };
    let (dir, gsd, config) = files("master");
    let _gw = gateway(
        &[
            "--config",
            config.to_str().unwrap(),
            "--profibus",
            pty.1.to_str().unwrap(),
            "--profibus-address",
            "5",
        ],
        1,
    );
    let out = common::interop_script(
        &py,
        "pyprofibus_master.py",
        &[
            pty.2.to_str().unwrap(),
            gsd.to_str().unwrap(),
            "5",
            "2",
            "20",
            "0",
        ],
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let lines: Vec<serde_json::Value> = out
        .lines()
        .filter_map(|l| serde_json::from_str(l).ok())
        .collect();
    let images: Vec<Vec<u8>> = lines
        .iter()
        .filter(|l| l["connected"] == true)
        .filter_map(|l| l["inputs"].as_str().map(hex))
        .filter(|b| b.len() == 56)
        .collect();
    assert!(
        images.len() >= 5,
        "pyprofibus was not in data exchange long enough:\n{out}"
    );
    let last = images.last().unwrap();
    for (slot, units) in [(0, 12u8), (1, 32)] {
        let m = &last[slot * 28..(slot + 1) * 28];
        assert!(f32_at(m, 0).is_finite(), "module {slot}: {m:02X?}");
        assert_eq!(m[20], units, "module {slot}: PV units");
        assert_eq!(m[23], 0, "module {slot}: quality good");
    }
    // PVs change over time.
    let pvs: Vec<f32> = images.iter().map(|b| f32_at(b, 0)).collect();
    assert!(pvs.windows(2).any(|w| w[0] != w[1]), "{pvs:?}");
    // The loop test: 12.5 mA with write counter 1 on module 0, done (2), the device's
    // loop current reads back 12.5 mA.
    let m0 = &last[0..28];
    assert_eq!(
        (m0[26], m0[27]),
        (1, 2),
        "write counter and result: {m0:02X?}"
    );
    assert!(
        (f32_at(m0, 16) - 12.5).abs() < 0.01,
        "loop current {}",
        f32_at(m0, 16)
    );

    // The master stops (its process ends) for longer than its 2 s watchdog: the
    // station clears its outputs and waits for parameters; a master that comes back
    // parameterises, configures and exchanges data again.
    std::thread::sleep(std::time::Duration::from_secs(3));
    let again = common::interop_script(
        &py,
        "pyprofibus_master.py",
        &[
            pty.2.to_str().unwrap(),
            gsd.to_str().unwrap(),
            "5",
            "2",
            "8",
        ],
    )
    .unwrap_or_else(|e| panic!("{e}"));
    assert!(
        again.lines().any(|l| l.contains("\"connected\": true")),
        "no data exchange after the master came back:\n{again}"
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// 93.75 kbit/s, a rate outside the termios table that both ends set by value
/// (hart-serial and pyserial): data exchange as at 19.2 kbit/s.
#[test]
fn pyprofibus_at_93_75_kbit_s() {
    let Some(py) = python() else { return };
    let Some(pty) = pty_pair() else { return };
    let (dir, gsd, config) = files("fast");
    let _gw = gateway(
        &[
            "--config",
            config.to_str().unwrap(),
            "--profibus",
            pty.1.to_str().unwrap(),
            "--profibus-baud",
            "93750",
        ],
        1,
    );
    let out = std::process::Command::new(&py)
        .arg(common::workspace().join("scripts/interop/pyprofibus_master.py"))
        .args([
            pty.2.to_str().unwrap(),
            gsd.to_str().unwrap(),
            "5",
            "2",
            "10",
        ])
        .env("PYPROFIBUS_BAUD", "93750")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        text.lines().any(|l| l.contains("\"connected\": true")),
        "no data exchange at 93.75 kbit/s:\n{text}"
    );
    let _ = std::fs::remove_dir_all(dir);
}
