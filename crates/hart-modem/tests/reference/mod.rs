//! A deliberately simple, independent Bell 202 / HART modem used only to check the
//! real one from outside: a textbook generator (one phase accumulator, the frequency
//! picked by the bit the sample falls in) and a textbook non-coherent receiver (a
//! 2nd-order band-pass, one-bit sliding quadrature correlators at 1200 and 2200 Hz, an
//! energy carrier detect, and a UART that samples each bit at its centre from the start
//! edge). It shares no code with `hart_modem` beyond nothing: only the protocol facts.

#![allow(dead_code)]

use std::f64::consts::PI;

/// A frame found by [`receive`].
#[derive(Debug, Clone, PartialEq)]
pub struct RefFrame {
    /// Time of the delimiter's start edge, seconds.
    pub t: f64,
    /// Delimiter through check byte.
    pub pdu: Vec<u8>,
    /// XOR over the PDU is zero.
    pub checksum_ok: bool,
}

fn bits_of(byte: u8) -> [u8; 11] {
    let mut b = [0u8; 11];
    for i in 0..8 {
        b[1 + i] = (byte >> i) & 1;
    }
    b[9] = u8::from(byte.count_ones() % 2 == 0);
    b[10] = 1;
    b
}

/// Generates frames as (preambles, pdu), each as one burst with 4 mark bits before and
/// after, `gap_s` of silence around them. `speed` scales tones and bit rate together.
/// Returns samples (volts) and each delimiter's start time.
pub fn generate_speed(
    fs: u32,
    amplitude_vpp: f64,
    frames: &[(usize, Vec<u8>)],
    gap_s: f64,
    speed: f64,
) -> (Vec<f32>, Vec<f64>) {
    let fs = f64::from(fs);
    let bit_t = 1.0 / (1200.0 * speed);
    let mut out = Vec::new();
    let mut times = Vec::new();
    let mut t_now = 0.0f64;
    let silence = |out: &mut Vec<f32>, t_now: &mut f64, secs: f64| {
        let n = (secs * fs).round() as usize;
        out.extend(std::iter::repeat_n(0.0f32, n));
        *t_now += n as f64 / fs;
    };
    for (pre, pdu) in frames {
        silence(&mut out, &mut t_now, gap_s);
        let mut bits: Vec<u8> = vec![1; 4];
        for b in std::iter::repeat_n(0xFFu8, *pre).chain(pdu.iter().copied()) {
            bits.extend(bits_of(b));
        }
        bits.extend([1u8; 4]);
        times.push(t_now + (4 + 11 * pre) as f64 * bit_t);
        let n = (bits.len() as f64 * bit_t * fs).round() as usize;
        let mut phase = 0.0f64;
        for i in 0..n {
            // Which bit sample i falls in, in exact rational arithmetic (a floating-point
            // division would put some boundary samples in the previous bit).
            let k = ((i as f64 * 1200.0 * speed + 1e-9 * fs) / fs).floor() as usize;
            let k = k.min(bits.len() - 1);
            let f = if bits[k] == 1 { 1200.0 } else { 2200.0 } * speed;
            out.push((amplitude_vpp / 2.0 * phase.sin()) as f32);
            phase += 2.0 * PI * f / fs;
        }
        t_now += n as f64 / fs;
    }
    silence(&mut out, &mut t_now, gap_s);
    (out, times)
}

/// [`generate_speed`] at the nominal rate.
pub fn generate(
    fs: u32,
    amplitude_vpp: f64,
    frames: &[(usize, Vec<u8>)],
    gap_s: f64,
) -> (Vec<f32>, Vec<f64>) {
    generate_speed(fs, amplitude_vpp, frames, gap_s, 1.0)
}

/// Decodes every frame.
pub fn receive(fs: u32, samples: &[f32]) -> Vec<RefFrame> {
    let fsf = f64::from(fs);
    let n_bit = (fsf / 1200.0).round() as usize;
    // Band-pass 900-2500 Hz: a high-pass and a low-pass biquad (RBJ cookbook).
    let biquad = |f0: f64, high: bool| {
        let w = 2.0 * PI * f0 / fsf;
        let alpha = w.sin() / (2.0 * 0.707);
        let c = w.cos();
        let (b0, b1, b2) = if high {
            ((1.0 + c) / 2.0, -(1.0 + c), (1.0 + c) / 2.0)
        } else {
            ((1.0 - c) / 2.0, 1.0 - c, (1.0 - c) / 2.0)
        };
        let a0 = 1.0 + alpha;
        [b0 / a0, b1 / a0, b2 / a0, -2.0 * c / a0, (1.0 - alpha) / a0]
    };
    let filters = [biquad(900.0, true), biquad(2500.0, false)];
    let mut state = [[0.0f64; 4]; 2];
    let x: Vec<f64> = samples
        .iter()
        .map(|&s| {
            let mut v = f64::from(s);
            for (f, st) in filters.iter().zip(state.iter_mut()) {
                let y = f[0] * v + f[1] * st[0] + f[2] * st[1] - f[3] * st[2] - f[4] * st[3];
                st[1] = st[0];
                st[0] = v;
                st[3] = st[2];
                st[2] = y;
                v = y;
            }
            v
        })
        .collect();
    // Sliding one-bit correlators: decision d[i] > 0 means mark; energy for carrier.
    let mut d = vec![0.0f64; x.len()];
    let mut level = vec![0.0f64; x.len()];
    let (mut mi, mut mq, mut si, mut sq) = (0.0, 0.0, 0.0, 0.0);
    for i in 0..x.len() {
        let t = i as f64 / fsf;
        let (wm, ws) = (2.0 * PI * 1200.0 * t, 2.0 * PI * 2200.0 * t);
        mi += x[i] * wm.cos();
        mq += x[i] * wm.sin();
        si += x[i] * ws.cos();
        sq += x[i] * ws.sin();
        if i >= n_bit {
            let j = i - n_bit;
            let tj = j as f64 / fsf;
            let (wm, ws) = (2.0 * PI * 1200.0 * tj, 2.0 * PI * 2200.0 * tj);
            mi -= x[j] * wm.cos();
            mq -= x[j] * wm.sin();
            si -= x[j] * ws.cos();
            sq -= x[j] * ws.sin();
        }
        let (em, es) = (mi * mi + mq * mq, si * si + sq * sq);
        d[i] = em - es;
        // Amplitude of the stronger tone, volts peak-to-peak.
        level[i] = 4.0 * em.max(es).sqrt() / n_bit as f64;
    }
    // The decision for a bit is best read at the end of its one-bit window.
    let carrier = |i: usize| level[i] > 0.1;
    let bit_at = |t: f64| -> Option<u8> {
        let i = (t * fsf).round() as usize;
        (i < d.len() && carrier(i)).then(|| u8::from(d[i] > 0.0))
    };
    // UART: find start edges (mark to space) while the carrier is on, then read the
    // character from its centre samples; re-synchronise on every start edge.
    let bit_t = 1.0 / 1200.0;
    let mut chars: Vec<(f64, u8, bool)> = Vec::new(); // (start time, byte, ok)
    let mut i = 1;
    while i < d.len() {
        if carrier(i) && d[i - 1] > 0.0 && d[i] <= 0.0 {
            // The window ending at i holds the edge about half a bit back... the decision
            // flips when the window is half full of the new tone.
            let edge = i as f64 / fsf - bit_t / 2.0;
            let sample = |k: usize| bit_at(edge + (k as f64 + 1.0) * bit_t);
            let all: Option<Vec<u8>> = (0..11).map(sample).collect();
            if let Some(b) = all {
                if b[0] == 0 {
                    let byte = (0..8).fold(0u8, |a, k| a | (b[1 + k] << k));
                    let ok = b[10] == 1 && (byte.count_ones() + u32::from(b[9])) % 2 == 1;
                    chars.push((edge, byte, ok));
                    // Continue from the middle of the stop bit.
                    i = ((edge + 10.5 * bit_t) * fsf) as usize;
                    continue;
                }
            }
        }
        i += 1;
    }
    // Frames: at least two good 0xFF, a delimiter, then by the byte count.
    let mut frames = Vec::new();
    let mut k = 0;
    while k < chars.len() {
        let mut pre = 0;
        while k < chars.len() && chars[k].1 == 0xFF && chars[k].2 {
            pre += 1;
            k += 1;
        }
        if pre < 2 || k >= chars.len() {
            k += 1;
            continue;
        }
        let start = k;
        let delim = chars[k].1;
        let addr = match delim & 0x80 {
            0 => 1,
            _ => 5,
        };
        if !matches!(delim & 0x7F, 0x01 | 0x02 | 0x06) {
            k += 1;
            continue;
        }
        let bc_at = start + 1 + addr + 1;
        if bc_at >= chars.len() {
            break;
        }
        let end = bc_at + 1 + usize::from(chars[bc_at].1) + 1;
        if end > chars.len() {
            break;
        }
        let pdu: Vec<u8> = chars[start..end].iter().map(|c| c.1).collect();
        let all_ok = chars[start..end].iter().all(|c| c.2);
        let checksum_ok = all_ok && pdu.iter().fold(0, |a, b| a ^ b) == 0;
        frames.push(RefFrame {
            t: chars[start].0,
            pdu,
            checksum_ok,
        });
        k = end;
    }
    frames
}
