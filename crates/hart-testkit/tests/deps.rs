//! What each tool links. The Python wheel is built on the library crates alone: the
//! codec, the host, the simulator and the HART-IP server. Building it must never
//! compile the command-line crate or the gateway's front ends and stores (OPC UA,
//! SQLite, PostgreSQL, the web server, the MQTT client, the well network, the
//! conformance tester), which would multiply its build time for nothing it uses.
//! Front ends do not lean on each other: PROFIBUS takes its value model and its serial
//! line from the crates below the front ends, not from the Modbus front end.

use std::process::Command;

/// The packages `package` links in a normal (non-dev, non-build) build, by name.
fn normal_dependencies(package: &str) -> Vec<String> {
    normal_dependencies_with(package, &[])
}

/// [`normal_dependencies`] with the package's `features` on.
fn normal_dependencies_with(package: &str, features: &[&str]) -> Vec<String> {
    let mut args = vec!["tree", "-p", package, "-e", "normal", "--prefix", "none"];
    let joined = features.join(",");
    if !features.is_empty() {
        args.extend(["--features", &joined]);
    }
    let out = Command::new(env!("CARGO"))
        .args(&args)
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/../.."))
        .output()
        .expect("cargo tree runs");
    assert!(
        out.status.success(),
        "cargo tree -p {package} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut names: Vec<String> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| l.split_whitespace().next().map(str::to_string))
        .collect();
    names.sort();
    names.dedup();
    names
}

#[test]
fn the_wheel_builds_no_front_end() {
    let linked = normal_dependencies("hartkit-py");
    let forbidden = [
        ("hartkit", "the command-line crate"),
        ("hart-gateway", "the gateway"),
        ("hart-web", "the dashboard"),
        ("hart-opcua", "the OPC UA front end"),
        ("hart-modbus", "the Modbus front end"),
        ("hart-profibus", "the PROFIBUS front end"),
        ("hart-sparkplug", "the Sparkplug B codec and MQTT client"),
        ("hart-sparkplug-edge", "the MQTT publisher"),
        ("hart-ingest", "the MQTT ingest"),
        ("hart-history", "the historian"),
        ("hart-recorder", "the historian's recorder"),
        ("hart-wells", "the well network"),
        ("hart-conform", "the conformance tester"),
        ("async-opcua", "OPC UA"),
        ("rusqlite", "SQLite"),
        ("libsqlite3-sys", "SQLite's C build"),
        ("tokio-postgres", "PostgreSQL"),
        ("axum", "the HTTP server"),
        ("rumqttc", "the MQTT client"),
        ("clap", "the command line's parser"),
    ];
    let found: Vec<String> = forbidden
        .iter()
        .filter(|(name, _)| linked.iter().any(|l| l == name))
        .map(|(name, what)| format!("{name} ({what})"))
        .collect();
    assert!(
        found.is_empty(),
        "the Python package (crates/hartkit-py) now links {}: take what it needs from a \
         library crate (hart-proto, hart-host, hart-sim) instead of depending on the crate \
         that brings these in; `cargo tree -p hartkit-py -i NAME` shows the path",
        found.join(", ")
    );
    // The libraries it is built on are still there (the check above is not vacuous).
    for needed in ["hart-proto", "hart-host", "hart-sim", "pyo3"] {
        assert!(linked.iter().any(|l| l == needed), "{needed} is missing");
    }
}

#[test]
fn profibus_does_not_link_modbus() {
    let linked = normal_dependencies_with("hart-profibus", &["hart-profibus/gateway"]);
    assert!(
        !linked.iter().any(|l| l == "hart-modbus"),
        "hart-profibus (with its gateway feature) now links hart-modbus: front ends do not \
         lean on each other; take the value model from hart-values and the serial line from \
         hart-serial's `aio`; `cargo tree -p hart-profibus -F gateway -i hart-modbus` shows \
         the path"
    );
    // What it takes instead is there (the check above is not vacuous).
    for needed in ["hart-values", "hart-serial", "hart-poller"] {
        assert!(linked.iter().any(|l| l == needed), "{needed} is missing");
    }
}

/// The ingest (a Sparkplug B host application storing into the historian) is built on
/// the codec and the store alone: hart-sparkplug and hart-history keep the polling
/// engine's adapters (hart-sparkplug-edge, hart-recorder) apart, so the ingest never
/// compiles the engine or the host's transports.
#[test]
fn the_ingest_does_not_link_the_polling_engine() {
    let linked = normal_dependencies("hart-ingest");
    let forbidden = [
        ("hart-poller", "the polling engine"),
        ("hart-host", "the HART master and its transports"),
        ("hart-sparkplug-edge", "the gateway's edge node"),
        ("hart-recorder", "the gateway's recorder"),
    ];
    let found: Vec<String> = forbidden
        .iter()
        .filter(|(name, _)| linked.iter().any(|l| l == name))
        .map(|(name, what)| format!("{name} ({what})"))
        .collect();
    assert!(
        found.is_empty(),
        "hart-ingest now links {}: take what it needs from hart-sparkplug (codec, metric \
         table, MQTT client) or hart-history (store) and keep engine code in \
         hart-sparkplug-edge or hart-recorder; `cargo tree -p hart-ingest -i NAME` shows the \
         path",
        found.join(", ")
    );
    for needed in ["hart-sparkplug", "hart-history", "rumqttc"] {
        assert!(linked.iter().any(|l| l == needed), "{needed} is missing");
    }
}
