//! Codec throughput: frames per second for a mix of command 0, 3 and 9 replies, for the
//! frame parser alone, for parsing plus typed decoding, and for the streaming deframer.
//! Run with `cargo bench -p hartkit --bench codec`; figures go to docs/benchmarks.md.

use criterion::{black_box, criterion_group, criterion_main, Criterion, Throughput};
use hart_proto::deframer::{Deframer, DeframerEvent};
use hart_proto::{decode_response, Frame};
use hartkit::hex;

const MIX: &[&str] = &[
    // Command 0 reply, HART 7.
    "FF FF FF FF FF 06 80 00 18 00 00 FE 26 06 05 07 01 02 18 00 12 34 56 05 04 00 01 00 00 26 00 26 01 28",
    // Command 3 reply, 4 dynamic variables (two unused).
    "FF FF FF FF FF 86 A6 06 12 34 56 03 1A 00 00 41 40 00 00 06 42 48 00 00 21 42 91 00 00 FA 7F A0 00 00 FA 7F A0 00 00 B0",
    // Command 9 reply, 2 slots and a time stamp.
    "FF FF FF FF FF 86 A6 06 12 34 56 09 17 00 00 00 00 41 06 42 48 00 00 C0 F5 00 27 41 40 00 00 C0 52 65 C0 00 21",
];

fn frames() -> Vec<Vec<u8>> {
    MIX.iter().map(|h| hex::parse(&[h]).unwrap()).collect()
}

fn bench(c: &mut Criterion) {
    let frames = frames();
    let mut g = c.benchmark_group("codec");
    g.throughput(Throughput::Elements(frames.len() as u64));
    g.bench_function("parse", |b| {
        b.iter(|| {
            for f in &frames {
                black_box(Frame::parse(black_box(f)).unwrap());
            }
        })
    });
    g.bench_function("parse+decode", |b| {
        b.iter(|| {
            for f in &frames {
                let fr = Frame::parse(black_box(f)).unwrap();
                black_box(decode_response(fr.command, fr.data).unwrap().unwrap());
            }
        })
    });
    let stream: Vec<u8> = frames.concat();
    g.bench_function("deframe+decode", |b| {
        let mut d = Deframer::default();
        b.iter(|| {
            d.feed(black_box(&stream), |e| {
                if let DeframerEvent::Frame(f) = e {
                    black_box(decode_response(f.command, f.data));
                }
            })
        })
    });
    g.bench_function("parse+json", |b| {
        b.iter(|| {
            for f in &frames {
                black_box(hartkit::json::frame(&Frame::parse(black_box(f)).unwrap()));
            }
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
