//! Dialling a telephone modem with Hayes AT commands: how the bureau's PC reaches a
//! well's data concentrator.
//!
//! The PC's serial port (a [`Transport`]) goes to a modem that is first in command
//! mode: command lines `AT...` end with CR, and the modem answers each with result
//! lines, verbal (`V1`: CR LF `OK` CR LF) or numeric (`V0`: `0` CR). [`dial`] sends
//! the initialisation string, then `ATD<number>`, and returns at `CONNECT`: from then
//! on the line is the data phase, where HART frames pass to the concentrator.
//! [`hang_up`] leaves the data phase with the escape sequence (`+++` between two
//! guard times of silence) and ends the call with `ATH`.
//!
//! The pieces under them are sans-IO and usable on their own: [`LineAssembler`]
//! cuts the modem's output into lines (CR LF, CR alone or LF alone), [`parse_result`]
//! recognises result codes, [`check_number`] validates a number before anything is
//! sent.
//!
//! Times are the transport's clock ([`Transport::now`]), so the functions run as well
//! on a serial port in real time as on a line in virtual time: every wait, the guard
//! times included, is a [`Transport::recv`] with a deadline.

use std::collections::VecDeque;
use std::fmt;
use std::io;
use std::time::Duration;

use hart_host::transport::Transport;
use tracing::{debug, warn};

/// Settings of a dial.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DialOptions {
    /// The concentrator's telephone number: digits, `*`, `#`, `+`, `,` (pause), `W`
    /// (wait for a dial tone), `T`/`P` (tone or pulse dialling from there on). Spaces,
    /// `-`, `(` and `)` may separate digits and are left out of what is sent. Checked
    /// by [`check_number`] before anything is sent.
    pub number: String,
    /// The command line sent first (without its CR), which must start with `AT`;
    /// empty to send none. Default `ATE0V1Q0`: echo off, verbal results, results on.
    pub init: String,
    /// How long `ATD` may take to give `CONNECT` or another result. Default 60 s
    /// (longer than the 50 s a modem waits for a carrier by default, register S7).
    pub connect_timeout: Duration,
    /// How long any other command may take to give its result. Default 3 s.
    pub command_timeout: Duration,
    /// The escape guard time: the silence kept before and after `+++`. Default 1.2 s,
    /// a little over the modems' default of 1 s (register S12 = 50).
    pub guard: Duration,
}

impl Default for DialOptions {
    fn default() -> Self {
        DialOptions {
            number: String::new(),
            init: "ATE0V1Q0".into(),
            connect_timeout: Duration::from_secs(60),
            command_timeout: Duration::from_secs(3),
            guard: Duration::from_millis(1200),
        }
    }
}

/// Why a dial or a hang-up failed.
#[derive(Debug)]
pub enum DialError {
    /// `BUSY`: the number is engaged.
    Busy,
    /// `NO CARRIER`: the other end did not answer with a carrier.
    NoCarrier,
    /// `NO DIALTONE` (or `NO DIAL TONE`): the modem heard no dial tone.
    NoDialtone,
    /// `NO ANSWER`: the other end rang and nobody answered.
    NoAnswer,
    /// The modem answered `ERROR` to a command.
    Error {
        /// The command line, without its CR.
        command: String,
    },
    /// The modem gave no result in time.
    Timeout {
        /// What was being waited for an answer to: the command line.
        waiting_for: String,
        /// How long was waited.
        after: Duration,
    },
    /// The number or the initialisation string cannot be sent; nothing was sent.
    /// The text says why.
    BadNumber(String),
    /// The serial line failed.
    Io(io::Error),
}

impl fmt::Display for DialError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DialError::Busy => write!(
                f,
                "the number is busy: the concentrator's line may be in use, try again later"
            ),
            DialError::NoCarrier => write!(
                f,
                "NO CARRIER: the other modem did not answer with a carrier (wrong number, the \
                 line dropped, or the concentrator's modem is off)"
            ),
            DialError::NoDialtone => write!(
                f,
                "the modem hears no dial tone: check the telephone cable to the wall socket"
            ),
            DialError::NoAnswer => write!(
                f,
                "NO ANSWER: the number rang but nobody answered: check the number and that \
                 the concentrator's modem is on and set to answer (register S0 not 0)"
            ),
            DialError::Error { command } => write!(
                f,
                "the modem answered ERROR to {command}: it does not take this command; check \
                 the initialisation string and the number"
            ),
            DialError::Timeout { waiting_for, after } => write!(
                f,
                "no answer from the modem to {waiting_for} after {after:?}: check the serial \
                 cable, the port's bit rate and that the modem is switched on"
            ),
            DialError::BadNumber(why) => write!(f, "{why}"),
            DialError::Io(e) => write!(f, "serial line to the modem: {e}"),
        }
    }
}

impl std::error::Error for DialError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            DialError::Io(e) => Some(e),
            _ => None,
        }
    }
}

impl From<io::Error> for DialError {
    fn from(e: io::Error) -> Self {
        DialError::Io(e)
    }
}

/// A result code of the modem.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ModemResult {
    /// `OK` (`0`).
    Ok,
    /// `CONNECT` with whatever follows it (`CONNECT 1200`, `CONNECT 2400/ARQ`): the
    /// line as the modem sent it, trimmed; numeric codes `1`, `5` and `10` give
    /// `CONNECT`, `CONNECT 1200` and `CONNECT 2400`.
    Connect(String),
    /// `RING` (`2`): a call is coming in.
    Ring,
    /// `NO CARRIER` (`3`).
    NoCarrier,
    /// `ERROR` (`4`).
    Error,
    /// `NO DIALTONE` or `NO DIAL TONE` (`6`).
    NoDialtone,
    /// `BUSY` (`7`).
    Busy,
    /// `NO ANSWER` (`8`).
    NoAnswer,
}

/// Recognises a result line, verbal (any case, spaces between words as they come) or
/// numeric. Other lines (command echoes, `CARRIER 1200`, `PROTOCOL: NONE`, ...) give
/// `None`.
pub fn parse_result(line: &str) -> Option<ModemResult> {
    let line = line.trim();
    let words: Vec<String> = line
        .split_whitespace()
        .map(|w| w.to_ascii_uppercase())
        .collect();
    let norm = words.join(" ");
    Some(match norm.as_str() {
        "OK" | "0" => ModemResult::Ok,
        "1" => ModemResult::Connect("CONNECT".into()),
        "5" => ModemResult::Connect("CONNECT 1200".into()),
        "10" => ModemResult::Connect("CONNECT 2400".into()),
        "RING" | "2" => ModemResult::Ring,
        "NO CARRIER" | "3" => ModemResult::NoCarrier,
        "ERROR" | "4" => ModemResult::Error,
        "NO DIALTONE" | "NO DIAL TONE" | "6" => ModemResult::NoDialtone,
        "BUSY" | "7" => ModemResult::Busy,
        "NO ANSWER" | "8" => ModemResult::NoAnswer,
        s if s == "CONNECT" || s.starts_with("CONNECT ") || s.starts_with("CONNECT/") => {
            ModemResult::Connect(line.to_string())
        }
        _ => return None,
    })
}

/// Whether `line` is the modem echoing a command line (`AT...` or `A/`), which it does
/// until `E0` takes effect.
fn is_echo(line: &str) -> bool {
    let l = line.trim_start().as_bytes();
    l.len() >= 2
        && l[0].eq_ignore_ascii_case(&b'A')
        && (l[1].eq_ignore_ascii_case(&b'T') || l[1] == b'/')
}

/// Cuts what a modem sends into lines. A line ends at CR LF, at CR alone or at LF
/// alone; the LF of a CR LF pair is swallowed even when it arrives in a later call.
/// Blank lines (and lines of spaces) are not returned. A line is cut at
/// [`LineAssembler::MAX_LINE`] bytes (the rest of it until its end is dropped); bytes
/// that are not UTF-8 become U+FFFD.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct LineAssembler {
    buf: Vec<u8>,
    after_cr: bool,
}

impl LineAssembler {
    /// The longest line kept, in bytes.
    pub const MAX_LINE: usize = 256;

    /// An assembler at the start of a line.
    pub fn new() -> Self {
        Self::default()
    }

    /// Takes one byte; returns the line it completes, if any, without its end.
    pub fn push(&mut self, byte: u8) -> Option<String> {
        let after_cr = std::mem::replace(&mut self.after_cr, false);
        match byte {
            b'\n' if after_cr => None,
            b'\r' | b'\n' => {
                self.after_cr = byte == b'\r';
                let line = String::from_utf8_lossy(&self.buf).trim().to_string();
                self.buf.clear();
                (!line.is_empty()).then_some(line)
            }
            _ => {
                if self.buf.len() < Self::MAX_LINE {
                    self.buf.push(byte);
                }
                None
            }
        }
    }

    /// Takes `bytes`; returns the lines they complete, in order.
    pub fn feed(&mut self, bytes: &[u8]) -> Vec<String> {
        bytes.iter().filter_map(|&b| self.push(b)).collect()
    }

    /// The bytes of the line begun and not ended yet.
    pub fn pending(&self) -> &[u8] {
        &self.buf
    }

    /// Whether the last byte taken was a CR (its LF may still come).
    pub fn after_cr(&self) -> bool {
        self.after_cr
    }

    /// Drops the line begun (a CR just taken still swallows the LF after it).
    pub fn clear(&mut self) {
        self.buf.clear();
    }
}

/// Checks a telephone number and returns the dial string sent after `ATD`: the
/// separators (spaces, `-`, `(`, `)`) left out, the letters in upper case. Allowed:
/// digits, `*`, `#`, `+`, `,` (pause), `W` (wait for a dial tone), `T` and `P` (tone or
/// pulse dialling). At least one digit; at most 40 characters.
pub fn check_number(number: &str) -> Result<String, DialError> {
    const ALLOWED: &str = "use digits, '*', '#', '+', ',' (pause), 'W' (wait for a dial tone) \
                           and 'T' or 'P' (tone or pulse dialling)";
    if number.trim().is_empty() {
        return Err(DialError::BadNumber(
            "no telephone number given: give the number of the concentrator's line".into(),
        ));
    }
    let mut out = String::new();
    for (i, c) in number.chars().enumerate() {
        match c {
            '\r' | '\n' => {
                return Err(DialError::BadNumber(format!(
                    "the telephone number {number:?} contains a line break at position {}: a \
                     number is one line; {ALLOWED}",
                    i + 1
                )))
            }
            '0'..='9' | '*' | '#' | '+' | ',' => out.push(c),
            'W' | 'w' | 'T' | 't' | 'P' | 'p' => out.push(c.to_ascii_uppercase()),
            ' ' | '-' | '(' | ')' => {}
            _ => {
                return Err(DialError::BadNumber(format!(
                    "the telephone number {number:?} has {c:?} at position {}: {ALLOWED}",
                    i + 1
                )))
            }
        }
    }
    if !out.chars().any(|c| c.is_ascii_digit()) {
        return Err(DialError::BadNumber(format!(
            "the telephone number {number:?} has no digits"
        )));
    }
    if out.len() > 40 {
        return Err(DialError::BadNumber(format!(
            "the telephone number {number:?} makes a dial string of {} characters; modems \
             take at most 40",
            out.len()
        )));
    }
    Ok(out)
}

/// Checks the initialisation string: one line, printable ASCII, starting with `AT`.
fn check_init(init: &str) -> Result<(), DialError> {
    if !init.is_ascii() || init.chars().any(|c| c.is_ascii_control()) {
        return Err(DialError::BadNumber(format!(
            "the initialisation string {init:?} contains a control character or a line \
             break: give one command line, without its CR"
        )));
    }
    if !is_echo(init) || init.trim_start().as_bytes()[1] == b'/' {
        return Err(DialError::BadNumber(format!(
            "the initialisation string {init:?} does not start with AT: the modem ignores \
             command lines that do not"
        )));
    }
    Ok(())
}

fn micros(d: Duration) -> u64 {
    d.as_micros().min(u128::from(u64::MAX)) as u64
}

/// How long [`dial`] waits, after a `CONNECT` line ended by a CR alone, for the LF that
/// may follow it, µs.
const LF_WAIT_US: u64 = 50_000;

/// The modem's output as lines, read from a transport.
#[derive(Default)]
struct Reader {
    asm: LineAssembler,
    lines: VecDeque<String>,
}

impl Reader {
    fn take(&mut self, bytes: &[(u8, u64)]) {
        for &(b, _) in bytes {
            if let Some(l) = self.asm.push(b) {
                debug!(line = %l, "modem");
                self.lines.push_back(l);
            }
        }
    }

    /// Forgets lines read and not used (stale results) before a new command.
    fn clear(&mut self) {
        for l in self.lines.drain(..) {
            debug!(line = %l, "modem line dropped before the next command");
        }
        self.asm.clear();
    }

    /// The next line, reading until `deadline`; `None` at the deadline.
    async fn next_line<T: Transport>(
        &mut self,
        t: &mut T,
        deadline: u64,
    ) -> io::Result<Option<String>> {
        loop {
            if let Some(l) = self.lines.pop_front() {
                return Ok(Some(l));
            }
            if t.now() >= deadline {
                return Ok(None);
            }
            let got = t.recv(deadline).await?;
            if got.is_empty() {
                return Ok(None);
            }
            self.take(&got);
        }
    }

    /// The next result, skipping echoes and lines that are no result; `None` at the
    /// deadline.
    async fn next_result<T: Transport>(
        &mut self,
        t: &mut T,
        deadline: u64,
    ) -> io::Result<Option<ModemResult>> {
        while let Some(line) = self.next_line(t, deadline).await? {
            if is_echo(&line) {
                debug!(line = %line, "command echo ignored");
                continue;
            }
            match parse_result(&line) {
                Some(r) => return Ok(Some(r)),
                None => debug!(line = %line, "not a result, ignored"),
            }
        }
        Ok(None)
    }
}

/// Sends one command line (CR added).
async fn send_line<T: Transport>(t: &mut T, command: &str) -> io::Result<()> {
    debug!(command, "to modem");
    t.send(format!("{command}\r").as_bytes()).await
}

/// Sends `command` and waits for `OK`; `ERROR` fails; other results (a stale
/// `NO CARRIER`, `RING`) are passed over.
async fn command<T: Transport>(
    t: &mut T,
    rd: &mut Reader,
    command: &str,
    timeout: Duration,
) -> Result<(), DialError> {
    rd.clear();
    send_line(t, command).await?;
    let deadline = t.now().saturating_add(micros(timeout));
    loop {
        match rd.next_result(t, deadline).await? {
            None => {
                return Err(DialError::Timeout {
                    waiting_for: command.into(),
                    after: timeout,
                })
            }
            Some(ModemResult::Ok) => return Ok(()),
            Some(ModemResult::Error) => {
                return Err(DialError::Error {
                    command: command.into(),
                })
            }
            Some(other) => debug!(?other, command, "result passed over"),
        }
    }
}

/// Lets time pass until `until` without sending, reading what arrives into `rd`.
async fn quiet_until<T: Transport>(t: &mut T, rd: &mut Reader, until: u64) -> io::Result<()> {
    while t.now() < until {
        let got = t.recv(until).await?;
        if got.is_empty() {
            break;
        }
        rd.take(&got);
    }
    Ok(())
}

/// Dials the concentrator: checks the number (nothing is sent when it is bad), sends
/// [`DialOptions::init`] and waits for `OK`, sends `ATD<number>` and waits for
/// `CONNECT`. Returns the `CONNECT` line the modem sent ("CONNECT 1200"), for the log;
/// the line is then in the data phase.
///
/// Results are read in either form (verbal or numeric, any case), lines ended by CR
/// LF, CR or LF; blank lines, command echoes (a modem echoes the initialisation line
/// itself before `E0` takes effect) and informational lines (`CARRIER 1200`,
/// `PROTOCOL: NONE`) are passed over, and so are `RING` and stray `OK` or
/// `NO CARRIER` lines before the one awaited. `BUSY`, `NO CARRIER`, `NO DIALTONE`,
/// `NO ANSWER` and `ERROR` after `ATD` fail with the matching [`DialError`].
///
/// Bytes that arrive after the `CONNECT` line in the same read are dropped (with a
/// warning in the log): there should be none, as the data phase starts with the PC's
/// request. A `CONNECT` line ended by CR alone gets 50 ms for its LF, so that the LF
/// is not taken for data.
pub async fn dial<T: Transport>(t: &mut T, opts: &DialOptions) -> Result<String, DialError> {
    let number = check_number(&opts.number)?;
    let init = opts.init.trim();
    if !init.is_empty() {
        check_init(init)?;
    }
    let mut rd = Reader::default();
    if !init.is_empty() {
        command(t, &mut rd, init, opts.command_timeout).await?;
    }
    let atd = format!("ATD{number}");
    rd.clear();
    send_line(t, &atd).await?;
    let deadline = t.now().saturating_add(micros(opts.connect_timeout));
    loop {
        let failure = match rd.next_result(t, deadline).await? {
            None => DialError::Timeout {
                waiting_for: atd,
                after: opts.connect_timeout,
            },
            Some(ModemResult::Connect(line)) => {
                finish_connect(t, &mut rd).await?;
                return Ok(line);
            }
            Some(ModemResult::Busy) => DialError::Busy,
            Some(ModemResult::NoCarrier) => DialError::NoCarrier,
            Some(ModemResult::NoDialtone) => DialError::NoDialtone,
            Some(ModemResult::NoAnswer) => DialError::NoAnswer,
            Some(ModemResult::Error) => DialError::Error { command: atd },
            Some(other @ (ModemResult::Ok | ModemResult::Ring)) => {
                debug!(?other, "result passed over while dialling");
                continue;
            }
        };
        return Err(failure);
    }
}

/// After `CONNECT`: takes the LF of a line ended by CR alone, and drops (with a
/// warning) whatever else came with it.
async fn finish_connect<T: Transport>(t: &mut T, rd: &mut Reader) -> io::Result<()> {
    let mut dropped: usize = rd.lines.iter().map(|l| l.len() + 1).sum();
    dropped += rd.asm.pending().len();
    if dropped == 0 && rd.asm.after_cr() {
        let until = t.now().saturating_add(LF_WAIT_US);
        let got = t.recv(until).await?;
        let data = match got.first() {
            Some((b'\n', _)) => &got[1..],
            _ => &got[..],
        };
        dropped += data.len();
    }
    if dropped > 0 {
        warn!(
            bytes = dropped,
            "bytes after the modem's CONNECT line dropped (the data phase starts with our request)"
        );
    }
    rd.lines.clear();
    rd.asm = LineAssembler::new();
    Ok(())
}

/// Ends the call: keeps silent for the guard time, sends `+++` (no CR), keeps silent
/// for the guard time again and waits (up to a further [`DialOptions::command_timeout`])
/// for the modem's `OK` from command mode; then sends `ATH` and waits for `OK`.
///
/// A modem whose line already dropped is in command mode: it answers the escape with
/// `NO CARRIER` or not at all, and that is passed over; `NO CARRIER` in answer to
/// `ATH` is taken as done too. A modem that answers `ATH` with `ERROR` (the `+++`
/// went into its command line) gets `ATH` once more; a second `ERROR` fails with
/// [`DialError::Error`]. No answer at all to `ATH` fails with [`DialError::Timeout`]
/// (the escape did not reach the modem's command mode, so `ATH` went down the line
/// as data: check the modem's guard time, register S12, against
/// [`DialOptions::guard`]). Data from the other end arriving meanwhile is dropped.
pub async fn hang_up<T: Transport>(t: &mut T, opts: &DialOptions) -> Result<(), DialError> {
    let guard = micros(opts.guard);
    let mut rd = Reader::default();
    let until = t.now().saturating_add(guard);
    quiet_until(t, &mut rd, until).await?;
    rd.clear();
    debug!("escape +++ to modem");
    t.send(b"+++").await?;
    let sent = t.now();
    let deadline = sent
        .saturating_add(guard)
        .saturating_add(micros(opts.command_timeout));
    loop {
        match rd.next_result(t, deadline).await? {
            None => {
                debug!("no answer to the escape; going on with ATH");
                break;
            }
            Some(ModemResult::Ok) => break,
            Some(ModemResult::NoCarrier) => {
                debug!("NO CARRIER around the escape: the line had dropped");
                break;
            }
            Some(other) => debug!(?other, "result passed over after the escape"),
        }
    }
    // Never send before the guard time after "+++" is over.
    quiet_until(t, &mut rd, sent.saturating_add(guard)).await?;
    for attempt in 0..2 {
        rd.clear();
        send_line(t, "ATH").await?;
        let deadline = t.now().saturating_add(micros(opts.command_timeout));
        loop {
            match rd.next_result(t, deadline).await? {
                None => {
                    return Err(DialError::Timeout {
                        waiting_for: "ATH".into(),
                        after: opts.command_timeout,
                    })
                }
                Some(ModemResult::Ok | ModemResult::NoCarrier) => return Ok(()),
                Some(ModemResult::Error) if attempt == 0 => {
                    debug!("ERROR to ATH; once more on a clean command line");
                    break;
                }
                Some(ModemResult::Error) => {
                    return Err(DialError::Error {
                        command: "ATH".into(),
                    })
                }
                Some(other) => debug!(?other, "result passed over after ATH"),
            }
        }
    }
    unreachable!("the second ATH returns")
}

#[cfg(test)]
mod tests {
    use super::*;
    use hart_link::TimingProfile;

    /// What the scripted modem answers to one send: (delay after the send, bytes).
    type Reply = Vec<(u64, Vec<u8>)>;

    /// An in-memory line in virtual time: a scripted modem answers what is sent.
    struct Scripted {
        now: u64,
        inbox: Vec<(u64, Vec<u8>)>,
        sent: Vec<(u64, String)>,
        modem: Box<dyn FnMut(&str) -> Reply>,
    }

    impl Scripted {
        fn new(modem: impl FnMut(&str) -> Reply + 'static) -> Self {
            Scripted {
                now: 1_000_000,
                inbox: vec![],
                sent: vec![],
                modem: Box::new(modem),
            }
        }

        /// Bytes the modem sends at `at`, whatever is sent to it.
        fn deliver(&mut self, at: u64, bytes: &[u8]) {
            self.inbox.push((at, bytes.to_vec()));
            self.inbox.sort_by_key(|(t, _)| *t);
        }

        fn sent(&self) -> Vec<&str> {
            self.sent.iter().map(|(_, s)| s.as_str()).collect()
        }
    }

    impl Transport for Scripted {
        fn profile(&self) -> TimingProfile {
            TimingProfile::fsk()
        }
        fn now(&self) -> u64 {
            self.now
        }
        async fn send(&mut self, bytes: &[u8]) -> io::Result<()> {
            let text = String::from_utf8_lossy(bytes).into_owned();
            for (delay, b) in (self.modem)(&text) {
                let at = self.now + delay;
                self.deliver(at, &b);
            }
            self.sent.push((self.now, text));
            Ok(())
        }
        async fn recv(&mut self, deadline: u64) -> io::Result<Vec<(u8, u64)>> {
            match self.inbox.first() {
                Some((at, _)) if *at <= deadline => {
                    let (at, bytes) = self.inbox.remove(0);
                    self.now = self.now.max(at);
                    Ok(bytes.into_iter().map(|b| (b, at)).collect())
                }
                _ => {
                    self.now = self.now.max(deadline);
                    Ok(vec![])
                }
            }
        }
        fn describe(&self) -> String {
            "scripted modem".into()
        }
    }

    /// A modem answering each command by its start: the first rule whose prefix the
    /// sent text starts with gives (delay in ms, answer); no rule, no answer.
    fn modem(rules: &[(&'static str, u64, &'static str)]) -> impl FnMut(&str) -> Reply {
        let rules = rules.to_vec();
        move |sent: &str| {
            rules
                .iter()
                .find(|(p, _, _)| sent.starts_with(p))
                .map(|(_, ms, a)| vec![(ms * 1000, a.as_bytes().to_vec())])
                .unwrap_or_default()
        }
    }

    fn opts(number: &str) -> DialOptions {
        DialOptions {
            number: number.into(),
            ..Default::default()
        }
    }

    #[test]
    fn lines_end_at_cr_lf_cr_or_lf() {
        let mut a = LineAssembler::new();
        assert_eq!(a.feed(b"\r\nOK\r\n"), ["OK"]);
        assert_eq!(a.feed(b"0\r1\r"), ["0", "1"]);
        assert_eq!(a.feed(b"\nBUSY\nNO CARRIER\n\n"), ["BUSY", "NO CARRIER"]);
        // A CR LF split over two reads is one end; the blank lines are not lines.
        assert_eq!(a.feed(b"CONNECT 1200\r"), ["CONNECT 1200"]);
        assert!(a.after_cr());
        assert_eq!(a.feed(b"\n"), Vec::<String>::new());
        assert_eq!(a.feed(b"\r\r\n\n  \r\n"), Vec::<String>::new());
        // Byte by byte, and a line still open.
        let mut got = vec![];
        for &b in b"ATE0V1Q0\r\r\nOK\r\nRIN" {
            got.extend(a.push(b));
        }
        assert_eq!(got, ["ATE0V1Q0", "OK"]);
        assert_eq!(a.pending(), b"RIN");
        a.clear();
        assert_eq!(a.feed(b"G\r\n"), ["G"]);
        // LF CR is two ends (an empty line between them).
        assert_eq!(a.feed(b"A\n\rB\r\n"), ["A", "B"]);
        // Spaces around a result go; a runaway line is cut.
        assert_eq!(a.feed(b"  OK \r\n"), ["OK"]);
        let long = vec![b'x'; 1000];
        let got = a.feed(&[&long[..], b"\r\n"].concat());
        assert_eq!(got[0].len(), LineAssembler::MAX_LINE);
        assert_eq!(a.feed(b"\xff\xfeOK\r"), ["\u{fffd}\u{fffd}OK"]);
    }

    #[test]
    fn results_are_read_verbal_or_numeric_in_any_case() {
        use ModemResult as R;
        let cases: &[(&str, Option<ModemResult>)] = &[
            ("OK", Some(R::Ok)),
            ("ok", Some(R::Ok)),
            ("0", Some(R::Ok)),
            ("CONNECT", Some(R::Connect("CONNECT".into()))),
            ("CONNECT 1200", Some(R::Connect("CONNECT 1200".into()))),
            (
                "connect 2400/ARQ",
                Some(R::Connect("connect 2400/ARQ".into())),
            ),
            ("1", Some(R::Connect("CONNECT".into()))),
            ("5", Some(R::Connect("CONNECT 1200".into()))),
            ("10", Some(R::Connect("CONNECT 2400".into()))),
            ("RING", Some(R::Ring)),
            ("2", Some(R::Ring)),
            ("NO CARRIER", Some(R::NoCarrier)),
            ("No  Carrier", Some(R::NoCarrier)),
            ("3", Some(R::NoCarrier)),
            ("ERROR", Some(R::Error)),
            ("4", Some(R::Error)),
            ("NO DIALTONE", Some(R::NoDialtone)),
            ("no dial tone", Some(R::NoDialtone)),
            ("6", Some(R::NoDialtone)),
            ("BUSY", Some(R::Busy)),
            ("7", Some(R::Busy)),
            ("NO ANSWER", Some(R::NoAnswer)),
            ("8", Some(R::NoAnswer)),
            ("CONNECTED", None),
            ("CARRIER 1200", None),
            ("PROTOCOL: NONE", None),
            ("ATDT5551234", None),
            ("9", None),
            ("", None),
        ];
        for (line, want) in cases {
            assert_eq!(&parse_result(line), want, "{line:?}");
        }
        assert!(is_echo("ATE0V1Q0") && is_echo("atdt123") && is_echo("A/"));
        assert!(!is_echo("OK") && !is_echo("A"));
    }

    #[test]
    fn numbers_are_checked_before_dialling() {
        assert_eq!(check_number("5551234").unwrap(), "5551234");
        assert_eq!(check_number("T 555-1234").unwrap(), "T5551234");
        assert_eq!(check_number("p9,w(030) 123 45").unwrap(), "P9,W03012345");
        assert_eq!(check_number("+49 30 1234#*").unwrap(), "+49301234#*");
        for bad in [
            "",
            "   ",
            "555\r1234",
            "5551234\n",
            "555x1234",
            "ATDT5551234",
            "555;",
            "T,W",
            "1234567890123456789012345678901234567890123",
        ] {
            match check_number(bad) {
                Err(DialError::BadNumber(why)) => {
                    assert!(why.contains("number"), "{why}");
                    if !bad.trim().is_empty() {
                        assert!(why.contains(&format!("{bad:?}")), "{why}");
                    }
                }
                other => panic!("{bad:?}: {other:?}"),
            }
        }
        let Err(DialError::BadNumber(why)) = check_number("555x") else {
            panic!()
        };
        assert!(why.contains("'x' at position 4"), "{why}");
        let Err(DialError::BadNumber(why)) = check_number("555\r") else {
            panic!()
        };
        assert!(why.contains("line break"), "{why}");
    }

    #[test]
    fn messages_say_what_to_check() {
        let s = |e: DialError| e.to_string();
        assert_eq!(
            s(DialError::NoDialtone),
            "the modem hears no dial tone: check the telephone cable to the wall socket"
        );
        assert_eq!(
            s(DialError::Busy),
            "the number is busy: the concentrator's line may be in use, try again later"
        );
        assert_eq!(
            s(DialError::NoCarrier),
            "NO CARRIER: the other modem did not answer with a carrier (wrong number, the \
             line dropped, or the concentrator's modem is off)"
        );
        assert_eq!(
            s(DialError::Timeout {
                waiting_for: "ATE0V1Q0".into(),
                after: Duration::from_secs(3)
            }),
            "no answer from the modem to ATE0V1Q0 after 3s: check the serial cable, the \
             port's bit rate and that the modem is switched on"
        );
        assert!(s(DialError::NoAnswer).contains("S0"));
        assert!(s(DialError::Error {
            command: "ATX9".into()
        })
        .contains("ERROR to ATX9"));
        let io = DialError::from(io::Error::other("gone"));
        assert!(s(io).contains("gone"));
        let io = DialError::from(io::Error::other("gone"));
        assert!(std::error::Error::source(&io).is_some());
    }

    #[tokio::test]
    async fn dial_connects_past_echoes_and_information() {
        // A modem at factory settings echoes the init line; then E0 holds.
        let mut t = Scripted::new(modem(&[
            ("ATE0V1Q0\r", 20, "ATE0V1Q0\r\r\nOK\r\n"),
            (
                "ATDT5551234\r",
                9_000,
                "\r\nRING\r\n\r\nCARRIER 1200\r\n\r\nPROTOCOL: NONE\r\n\r\nCONNECT 1200\r\n",
            ),
        ]));
        let line = dial(&mut t, &opts("T555-1234")).await.unwrap();
        assert_eq!(line, "CONNECT 1200");
        assert_eq!(t.sent(), ["ATE0V1Q0\r", "ATDT5551234\r"]);
        // The data phase starts clean.
        t.deliver(t.now + 100_000, b"\xff\xff\x06");
        let got = t.recv(t.now + 1_000_000).await.unwrap();
        assert_eq!(got.iter().map(|c| c.0).collect::<Vec<_>>(), b"\xff\xff\x06");
    }

    #[tokio::test]
    async fn numeric_cr_only_and_lf_only_results() {
        // V0: "0\r", "5\r"; the CR-ended CONNECT waits briefly for an LF that never
        // comes, and data after that is the data phase's.
        let mut t = Scripted::new(modem(&[("ATE0V0", 10, "0\r"), ("ATD", 3_000, "5\r")]));
        let o = DialOptions {
            init: "ATE0V0".into(),
            ..opts("123")
        };
        assert_eq!(dial(&mut t, &o).await.unwrap(), "CONNECT 1200");
        // LF only, lower case, an LF split from its CR into a later read.
        let mut t = Scripted::new(modem(&[
            ("ATE0V1Q0", 10, "\nok\n"),
            ("ATD", 3_000, "\nconnect 2400\r"),
        ]));
        assert_eq!(dial(&mut t, &opts("123")).await.unwrap(), "connect 2400");
        let mut t = Scripted::new(modem(&[
            ("ATE0V1Q0", 10, "\r\nOK\r\n"),
            ("ATD", 3_000, "\r\nCONNECT 1200\r"),
        ]));
        // The LF comes 8 ms after the CR, in a read of its own; then data.
        let mut o = opts("123");
        o.connect_timeout = Duration::from_secs(10);
        let at = 1_000_000 + 10_000 + 3_000_000 + 8_000;
        t.deliver(at, b"\n");
        t.deliver(at + 500_000, b"data");
        assert_eq!(dial(&mut t, &o).await.unwrap(), "CONNECT 1200");
        let got = t.recv(t.now + 1_000_000).await.unwrap();
        assert_eq!(got.iter().map(|c| c.0).collect::<Vec<_>>(), b"data");
    }

    #[tokio::test]
    async fn each_failure_of_the_dial() {
        type Check = fn(&DialError) -> bool;
        let cases: &[(&'static str, Check)] = &[
            ("\r\nBUSY\r\n", |e| matches!(e, DialError::Busy)),
            ("\r\nNO CARRIER\r\n", |e| matches!(e, DialError::NoCarrier)),
            ("\r\nNO DIALTONE\r\n", |e| {
                matches!(e, DialError::NoDialtone)
            }),
            ("\r\nNO DIAL TONE\r\n", |e| {
                matches!(e, DialError::NoDialtone)
            }),
            ("\r\nNO ANSWER\r\n", |e| matches!(e, DialError::NoAnswer)),
            ("7\r", |e| matches!(e, DialError::Busy)),
            (
                "\r\nOK\r\n\r\nERROR\r\n",
                |e| matches!(e, DialError::Error { command } if command == "ATD555"),
            ),
        ];
        for (answer, ok) in cases {
            let mut t = Scripted::new(modem(&[
                ("ATE0V1Q0", 10, "\r\nOK\r\n"),
                ("ATD555", 2_000, answer),
            ]));
            let e = dial(&mut t, &opts("555")).await.unwrap_err();
            assert!(ok(&e), "{answer:?}: {e:?}");
        }
    }

    #[tokio::test]
    async fn errors_and_silence_before_and_after_atd() {
        // ERROR to the initialisation string: ATD is never sent.
        let mut t = Scripted::new(modem(&[("ATE0V1Q0", 10, "\r\nERROR\r\n")]));
        let e = dial(&mut t, &opts("555")).await.unwrap_err();
        assert!(
            matches!(&e, DialError::Error { command } if command == "ATE0V1Q0"),
            "{e:?}"
        );
        assert_eq!(t.sent(), ["ATE0V1Q0\r"]);
        // A modem switched off: the init times out after the command time-out.
        let mut t = Scripted::new(modem(&[]));
        let t0 = t.now;
        let e = dial(&mut t, &opts("555")).await.unwrap_err();
        assert!(
            matches!(&e, DialError::Timeout { waiting_for, after }
                if waiting_for == "ATE0V1Q0" && *after == Duration::from_secs(3)),
            "{e:?}"
        );
        assert_eq!(t.now - t0, 3_000_000);
        assert!(e
            .to_string()
            .contains("no answer from the modem to ATE0V1Q0 after 3s"));
        // OK to init, then nothing: ATD times out after the connect time-out.
        let mut t = Scripted::new(modem(&[("ATE0V1Q0", 10, "\r\nOK\r\n")]));
        let t0 = t.now;
        let e = dial(&mut t, &opts("555")).await.unwrap_err();
        assert!(
            matches!(&e, DialError::Timeout { waiting_for, after }
                if waiting_for == "ATD555" && *after == Duration::from_secs(60)),
            "{e:?}"
        );
        assert_eq!(t.now - t0, 60_010_000);
        // No init at all.
        let mut t = Scripted::new(modem(&[("ATD555", 10, "\r\nCONNECT\r\n")]));
        let o = DialOptions {
            init: String::new(),
            ..opts("555")
        };
        assert_eq!(dial(&mut t, &o).await.unwrap(), "CONNECT");
        assert_eq!(t.sent(), ["ATD555\r"]);
    }

    #[tokio::test]
    async fn a_bad_number_or_init_sends_nothing() {
        for number in ["", "555x", "555\r\nATH"] {
            let mut t = Scripted::new(modem(&[("AT", 10, "\r\nOK\r\n")]));
            let e = dial(&mut t, &opts(number)).await.unwrap_err();
            assert!(matches!(e, DialError::BadNumber(_)), "{e:?}");
            assert!(t.sent.is_empty());
        }
        for init in ["E0V1", "ATE0\rATV1", "A/"] {
            let mut t = Scripted::new(modem(&[("AT", 10, "\r\nOK\r\n")]));
            let o = DialOptions {
                init: init.into(),
                ..opts("555")
            };
            let e = dial(&mut t, &o).await.unwrap_err();
            assert!(matches!(e, DialError::BadNumber(_)), "{e:?}");
            assert!(t.sent.is_empty());
        }
    }

    #[tokio::test]
    async fn stale_results_before_the_awaited_one_are_passed_over() {
        let mut t = Scripted::new(modem(&[
            ("ATE0V1Q0", 10, "\r\nNO CARRIER\r\n\r\nRING\r\n\r\nOK\r\n"),
            ("ATD", 100, "\r\nOK\r\n\r\nRING\r\n\r\nCONNECT 9600\r\n"),
        ]));
        assert_eq!(dial(&mut t, &opts("1")).await.unwrap(), "CONNECT 9600");
    }

    /// A modem in data mode: answers the escape after its own guard time, ATH with OK.
    fn online_modem(escape: Option<&'static str>, ath: &'static [&'static str]) -> Scripted {
        let mut n = 0;
        Scripted::new(move |sent: &str| match sent {
            "+++" => escape
                .map(|a| vec![(1_000_000, a.as_bytes().to_vec())])
                .unwrap_or_default(),
            "ATH\r" => {
                n += 1;
                ath.get(n - 1)
                    .map(|a| vec![(30_000, a.as_bytes().to_vec())])
                    .unwrap_or_default()
            }
            _ => vec![],
        })
    }

    #[tokio::test]
    async fn hang_up_keeps_the_guard_times() {
        let mut t = online_modem(Some("\r\nOK\r\n"), &["\r\nOK\r\n"]);
        // The concentrator's last reply is still arriving when hang_up starts.
        let t0 = t.now;
        t.deliver(t0 + 100_000, b"\xff\xff\x06\x81");
        hang_up(&mut t, &DialOptions::default()).await.unwrap();
        assert_eq!(t.sent(), ["+++", "ATH\r"]);
        let (plus, ath) = (t.sent[0].0, t.sent[1].0);
        assert_eq!(plus, t0 + 1_200_000);
        assert!(ath >= plus + 1_200_000, "{ath} {plus}");
        assert_eq!(ath, plus + 1_200_000);
        assert_eq!(t.now, ath + 30_000);
    }

    #[tokio::test]
    async fn hang_up_tolerates_a_dropped_line() {
        // No answer to the escape (the modem was in command mode already), NO CARRIER
        // to ATH: done, after waiting guard + command time-out for the escape.
        let mut t = online_modem(None, &["\r\nNO CARRIER\r\n"]);
        let t0 = t.now;
        hang_up(&mut t, &DialOptions::default()).await.unwrap();
        assert_eq!(t.sent[1].0 - t.sent[0].0, 4_200_000);
        assert!(t.now > t0);
        // NO CARRIER to the escape, OK to ATH; and a modem that says ERROR once.
        let mut t = online_modem(Some("\r\nNO CARRIER\r\n"), &["\r\nERROR\r\n", "\r\nOK\r\n"]);
        hang_up(&mut t, &DialOptions::default()).await.unwrap();
        assert_eq!(t.sent(), ["+++", "ATH\r", "ATH\r"]);
        // ERROR twice fails.
        let mut t = online_modem(Some("\r\nOK\r\n"), &["\r\nERROR\r\n", "\r\nERROR\r\n"]);
        let e = hang_up(&mut t, &DialOptions::default()).await.unwrap_err();
        assert!(
            matches!(&e, DialError::Error { command } if command == "ATH"),
            "{e:?}"
        );
    }

    #[tokio::test]
    async fn hang_up_fails_when_ath_gets_no_answer() {
        let mut t = online_modem(None, &[]);
        let o = DialOptions {
            guard: Duration::from_millis(500),
            command_timeout: Duration::from_secs(2),
            ..Default::default()
        };
        let e = hang_up(&mut t, &o).await.unwrap_err();
        assert!(
            matches!(&e, DialError::Timeout { waiting_for, after }
                if waiting_for == "ATH" && *after == Duration::from_secs(2)),
            "{e:?}"
        );
    }
}
