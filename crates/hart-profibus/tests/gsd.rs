//! The GSD file the gateway writes, read by an independent GSD parser (profirust's
//! `gsd-parser`, MIT/Apache): what a PLC engineering tool would import.

use hart_profibus::map::{gsd, module_cfg, GsdInfo, DEVICES_PER_STATION, INPUT_LEN, OUTPUT_LEN};

#[test]
fn gsd_parser_reads_the_generated_gsd() {
    let text = gsd(&GsdInfo {
        ident_number: 0x4854,
        version: "0.1.0".into(),
    });
    let g = gsd_parser::parser::parse(std::path::Path::new("hartkit.gsd"), &text)
        .unwrap_or_else(|e| panic!("{e}\n{text}"));
    assert_eq!(g.ident_number, 0x4854);
    assert_eq!(g.vendor, "hartkit");
    assert!(g.modular_station);
    assert_eq!(usize::from(g.max_modules), DEVICES_PER_STATION);
    assert_eq!(
        usize::from(g.max_input_length),
        DEVICES_PER_STATION * INPUT_LEN
    );
    assert_eq!(
        usize::from(g.max_output_length),
        DEVICES_PER_STATION * OUTPUT_LEN
    );
    assert!(g.freeze_mode_supported && g.sync_mode_supported);
    use gsd_parser::SupportedSpeeds as S;
    assert!(g
        .supported_speeds
        .contains(S::B9600 | S::B19200 | S::B45450 | S::B93750));
    assert_eq!(
        (
            g.max_tsdr.b9600,
            g.max_tsdr.b19200,
            g.max_tsdr.b45450,
            g.max_tsdr.b93750
        ),
        (100, 200, 450, 1000)
    );
    assert_eq!(g.available_modules.len(), 1);
    assert_eq!(g.available_modules[0].config, module_cfg());
    assert_eq!(g.unit_diag.bits.len(), DEVICES_PER_STATION);
}
