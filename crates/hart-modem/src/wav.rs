//! WAV files: a reader for the common PCM and float layouts and a mono writer.
//!
//! The reader ([`Wav::parse`]) takes the whole file as a byte slice and borrows the
//! sample data from it; nothing is copied until a channel is extracted with
//! [`Wav::channel`] or [`Wav::samples`]. It reads RIFF/WAVE files with:
//!
//! * integer PCM: 8-bit (unsigned), 16, 24 and 32-bit (signed, little-endian);
//! * IEEE float: 32 and 64-bit;
//! * `WAVE_FORMAT_EXTENSIBLE` with the PCM or IEEE float sub-format (a container wider
//!   than the valid bits, such as 24 valid bits in 32, is read as the container: the
//!   samples are left-justified, so full scale is still 1.0);
//! * any number of channels and any sample rate (the caller decides what it accepts);
//! * `RF64`/`BW64` files, whose 64-bit data size comes from the `ds64` chunk.
//!
//! Unknown chunks (`LIST`, `fact`, `cue `, `JUNK`, ...) are skipped, including the pad
//! byte that follows a chunk of odd size. A `data` chunk whose declared size runs past
//! the end of the file (a recording cut short) is read up to the end of the file and
//! reported by [`Wav::truncated`]; a size of `0xFFFFFFFF` (written by streaming
//! writers that cannot seek back to fill it in) means "up to the end of the file" and
//! is reported by [`Wav::streamed`]. A trailing partial frame is dropped.
//!
//! The input is untrusted: malformed files give a [`WavError`] that says what is wrong
//! and what to check, never a panic, and no allocation is sized from a declared length
//! (extracting a channel allocates at most one `f32` per frame actually present).
//!
//! The writer ([`write_mono`]) produces a minimal, standard mono file in 16-bit PCM or
//! 32-bit IEEE float.

use alloc::vec::Vec;
use core::fmt;
use core::iter::FusedIterator;
use core::slice::ChunksExact;

const TAG_PCM: u16 = 0x0001;
const TAG_FLOAT: u16 = 0x0003;
const TAG_EXTENSIBLE: u16 = 0xFFFE;

/// Bytes 2..16 of the `KSDATAFORMAT_SUBTYPE_*` GUIDs that wrap a plain format tag
/// (`{0000xxxx-0000-0010-8000-00AA00389B71}` stored little-endian): bytes 0..2 hold the
/// tag.
const GUID_TAIL: [u8; 14] = [
    0x00, 0x00, 0x00, 0x00, 0x10, 0x00, 0x80, 0x00, 0x00, 0xAA, 0x00, 0x38, 0x9B, 0x71,
];

/// How one sample is stored in a WAV file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SampleFormat {
    /// 8-bit unsigned integer PCM; silence is 128.
    U8,
    /// 16-bit signed integer PCM, little-endian.
    I16,
    /// 24-bit signed integer PCM, little-endian, packed in 3 bytes.
    I24,
    /// 32-bit signed integer PCM, little-endian.
    I32,
    /// 32-bit IEEE float, little-endian; full scale is ±1.0.
    F32,
    /// 64-bit IEEE float, little-endian; full scale is ±1.0.
    F64,
}

impl SampleFormat {
    /// Bytes per sample.
    pub const fn bytes(self) -> usize {
        match self {
            SampleFormat::U8 => 1,
            SampleFormat::I16 => 2,
            SampleFormat::I24 => 3,
            SampleFormat::I32 | SampleFormat::F32 => 4,
            SampleFormat::F64 => 8,
        }
    }

    /// Bits per sample.
    pub const fn bits(self) -> u16 {
        match self {
            SampleFormat::U8 => 8,
            SampleFormat::I16 => 16,
            SampleFormat::I24 => 24,
            SampleFormat::I32 | SampleFormat::F32 => 32,
            SampleFormat::F64 => 64,
        }
    }

    /// Whether the samples are IEEE floating point (otherwise integer PCM).
    pub const fn is_float(self) -> bool {
        matches!(self, SampleFormat::F32 | SampleFormat::F64)
    }
}

impl fmt::Display for SampleFormat {
    /// "16-bit PCM", "32-bit float", ...
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let kind = if self.is_float() { "float" } else { "PCM" };
        write!(f, "{}-bit {}", self.bits(), kind)
    }
}

/// Why a WAV file could not be read, or written.
///
/// The [`Display`](fmt::Display) text says what is wrong and what to check; it is meant
/// to be shown to the user as is.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum WavError {
    /// The input is shorter than the 12-byte RIFF header.
    TooShort {
        /// Length of the input in bytes.
        len: usize,
    },
    /// The input does not start with `RIFF` (or `RF64`/`BW64`).
    NotRiff {
        /// The first four bytes of the input.
        found: [u8; 4],
    },
    /// The input starts with `RIFX`: a big-endian WAV file, which is not supported.
    BigEndian,
    /// A RIFF file whose form type is not `WAVE` (an AVI file, for example).
    NotWave {
        /// The form type found at bytes 8..12.
        found: [u8; 4],
    },
    /// There is no `fmt ` chunk, so the sample encoding is unknown.
    NoFmtChunk,
    /// There is no `data` chunk.
    NoDataChunk,
    /// The `fmt ` chunk is too short for the fields its format needs.
    FmtTooShort {
        /// Length of the chunk body in bytes.
        len: usize,
        /// Minimum length for this format.
        needed: usize,
    },
    /// The file ends inside a chunk other than `data`, before the `fmt ` and `data`
    /// chunks were both found.
    TruncatedChunk {
        /// The chunk's identifier.
        id: [u8; 4],
        /// Byte offset of the chunk header in the file.
        offset: usize,
        /// The chunk's declared size in bytes.
        declared: u32,
        /// Bytes actually left after the chunk header.
        available: usize,
    },
    /// The format tag is not PCM or IEEE float (a compressed or companded encoding).
    UnsupportedEncoding {
        /// The format tag (from the `fmt ` chunk or the extensible sub-format GUID).
        tag: u16,
        /// Whether the tag came from a `WAVE_FORMAT_EXTENSIBLE` sub-format GUID.
        extensible: bool,
    },
    /// A `WAVE_FORMAT_EXTENSIBLE` sub-format GUID that does not wrap a format tag.
    UnsupportedSubformat {
        /// The sub-format GUID as stored in the file.
        guid: [u8; 16],
    },
    /// PCM or float with a sample width this reader does not handle.
    UnsupportedBits {
        /// Declared bits per sample.
        bits: u16,
        /// Whether the encoding is IEEE float (otherwise PCM).
        float: bool,
    },
    /// The `fmt ` chunk declares zero channels.
    ZeroChannels,
    /// The `fmt ` chunk declares a sample rate of 0 Hz.
    ZeroSampleRate,
    /// The `fmt ` chunk's block align (bytes per frame) does not match the channel
    /// count and sample width.
    BlockAlignMismatch {
        /// Declared block align in bytes.
        block_align: u16,
        /// Declared channel count.
        channels: u16,
        /// Declared sample format.
        format: SampleFormat,
    },
    /// [`Wav::channel`] or [`Wav::samples`] was asked for a channel the file lacks.
    NoSuchChannel {
        /// The channel asked for, numbered from 0.
        channel: u16,
        /// Channels in the file.
        channels: u16,
    },
    /// [`write_mono`] was given a sample rate of 0, or one so high that the byte rate
    /// does not fit in 32 bits.
    WriteSampleRate {
        /// The sample rate given, Hz.
        rate: u32,
    },
    /// [`write_mono`] was given more samples than a WAV file can hold (4 GiB of data).
    WriteTooLong {
        /// Number of samples given.
        samples: usize,
    },
}

/// Displays a chunk identifier or magic number in quotes, escaping non-printable bytes.
struct FourCc<'a>(&'a [u8; 4]);

impl fmt::Display for FourCc<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("'")?;
        for &b in self.0 {
            if (0x20..=0x7E).contains(&b) && b != b'\'' && b != b'\\' {
                write!(f, "{}", char::from(b))?;
            } else {
                write!(f, "\\x{b:02X}")?;
            }
        }
        f.write_str("'")
    }
}

/// Displays a GUID stored in the Microsoft mixed-endian layout in registry form.
struct Guid<'a>(&'a [u8; 16]);

impl fmt::Display for Guid<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let g = self.0;
        let [a0, a1, a2, a3, b0, b1, c0, c1, rest @ ..] = *g;
        write!(
            f,
            "{{{:08X}-{:04X}-{:04X}-",
            u32::from_le_bytes([a0, a1, a2, a3]),
            u16::from_le_bytes([b0, b1]),
            u16::from_le_bytes([c0, c1])
        )?;
        for (i, b) in rest.iter().enumerate() {
            if i == 2 {
                f.write_str("-")?;
            }
            write!(f, "{b:02X}")?;
        }
        f.write_str("}")
    }
}

/// A human name for a WAV format tag.
fn tag_name(tag: u16) -> &'static str {
    match tag {
        0x0000 => "unknown format",
        0x0002 => "Microsoft ADPCM",
        0x0006 => "A-law",
        0x0007 => "mu-law",
        0x0011 => "IMA ADPCM",
        0x0031 => "GSM 6.10",
        0x0050 => "MPEG audio",
        0x0055 => "MP3",
        0x00FF | 0x1600 | 0x1610 => "AAC",
        0xF1AC => "FLAC",
        _ => "a compressed or vendor-specific encoding",
    }
}

/// What a non-WAV file probably is, from its first four bytes.
fn magic_hint(found: &[u8; 4]) -> Option<&'static str> {
    match found {
        b"OggS" => Some("an Ogg file"),
        b"fLaC" => Some("a FLAC file"),
        b"FORM" => Some("an AIFF file"),
        b".snd" => Some("a Sun/NeXT AU file"),
        b"caff" => Some("a Core Audio (CAF) file"),
        [b'I', b'D', b'3', _] | [0xFF, 0xE0..=0xFF, _, _] => Some("an MP3 file"),
        _ => None,
    }
}

impl fmt::Display for WavError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            WavError::TooShort { len } => write!(
                f,
                "not a WAV file: it is only {len} bytes long, shorter than a RIFF header \
                 (12 bytes); check that the file was written completely"
            ),
            WavError::NotRiff { found } => {
                write!(
                    f,
                    "not a WAV file: the first 4 bytes are {}, expected 'RIFF'",
                    FourCc(found)
                )?;
                if let Some(kind) = magic_hint(found) {
                    write!(
                        f,
                        "; it looks like {kind}: convert it to WAV first \
                         (for example `sox in.ext -b 16 out.wav`)"
                    )?;
                }
                Ok(())
            }
            WavError::BigEndian => f.write_str(
                "unsupported WAV variant: the file starts with 'RIFX' (big-endian WAV); \
                 convert it to an ordinary little-endian WAV (for example \
                 `sox in.wav -b 16 out.wav`)",
            ),
            WavError::NotWave { found } => write!(
                f,
                "not a WAV file: it is a RIFF file of type {}, expected 'WAVE'",
                FourCc(found)
            ),
            WavError::NoFmtChunk => f.write_str(
                "no 'fmt ' chunk: the file does not say how its samples are encoded; \
                 it is damaged or was not written as a WAV file",
            ),
            WavError::NoDataChunk => f.write_str(
                "no 'data' chunk: the file has a header but no samples; check that the \
                 recording was not stopped before any audio was written",
            ),
            WavError::FmtTooShort { len, needed } => write!(
                f,
                "the 'fmt ' chunk is {len} bytes long but this format needs at least \
                 {needed}; the header is damaged"
            ),
            WavError::TruncatedChunk {
                id,
                offset,
                declared,
                available,
            } => write!(
                f,
                "the file ends inside the {} chunk at byte offset {offset}: it declares \
                 {declared} bytes but only {available} remain, and the samples come \
                 after it; the file is truncated or damaged",
                FourCc(id)
            ),
            WavError::UnsupportedEncoding { tag, extensible } => {
                write!(
                    f,
                    "unsupported encoding: {} (format tag 0x{tag:04X}",
                    tag_name(*tag)
                )?;
                if *extensible {
                    f.write_str(" in a WAVE_FORMAT_EXTENSIBLE sub-format")?;
                }
                f.write_str(
                    "); only PCM and IEEE float WAV files are read: convert it (for \
                     example `sox in.wav -e signed-integer -b 16 out.wav`)",
                )
            }
            WavError::UnsupportedSubformat { guid } => write!(
                f,
                "unsupported encoding: WAVE_FORMAT_EXTENSIBLE sub-format {}; only the \
                 PCM and IEEE float sub-formats are read: convert it (for example \
                 `sox in.wav -e signed-integer -b 16 out.wav`)",
                Guid(guid)
            ),
            WavError::UnsupportedBits { bits, float } => write!(
                f,
                "unsupported sample format: {bits}-bit {}; use 8, 16, 24 or 32-bit PCM \
                 or 32/64-bit float",
                if *float { "float" } else { "PCM" }
            ),
            WavError::ZeroChannels => {
                f.write_str("the 'fmt ' chunk declares 0 channels; the header is damaged")
            }
            WavError::ZeroSampleRate => f.write_str(
                "the 'fmt ' chunk declares a sample rate of 0 Hz; the header is damaged",
            ),
            WavError::BlockAlignMismatch {
                block_align,
                channels,
                format,
            } => write!(
                f,
                "inconsistent 'fmt ' chunk: the block align is {block_align} bytes per \
                 frame, but {channels} channel(s) of {format} take {} bytes; the header \
                 is damaged or uses a sample layout this reader does not support",
                u32::from(*channels) * u32::from(format.bits() / 8)
            ),
            WavError::NoSuchChannel { channel, channels } => write!(
                f,
                "there is no channel {channel}: the file has {channels} channel(s), \
                 numbered from 0"
            ),
            WavError::WriteSampleRate { rate } => write!(
                f,
                "cannot write a WAV file at {rate} Hz: the sample rate must be at least \
                 1 Hz and small enough for the byte rate to fit in 32 bits"
            ),
            WavError::WriteTooLong { samples } => write!(
                f,
                "cannot write {samples} samples: a WAV file holds at most 4 GiB of \
                 sample data; write a shorter signal or split it into several files"
            ),
        }
    }
}

impl core::error::Error for WavError {}

/// `N` bytes at `at`, if all are present.
fn array<const N: usize>(b: &[u8], at: usize) -> Option<[u8; N]> {
    b.get(at..at.checked_add(N)?)?.try_into().ok()
}

fn le16(b: &[u8], at: usize) -> Option<u16> {
    array(b, at).map(u16::from_le_bytes)
}

fn le32(b: &[u8], at: usize) -> Option<u32> {
    array(b, at).map(u32::from_le_bytes)
}

fn le64(b: &[u8], at: usize) -> Option<u64> {
    array(b, at).map(u64::from_le_bytes)
}

/// A length as `u64` (lossless on every supported target).
fn len64(n: usize) -> u64 {
    u64::try_from(n).unwrap_or(u64::MAX)
}

/// The decoded `fmt ` chunk.
struct Fmt {
    format: SampleFormat,
    channels: u16,
    sample_rate: u32,
}

fn parse_fmt(body: &[u8]) -> Result<Fmt, WavError> {
    let short = |needed| WavError::FmtTooShort {
        len: body.len(),
        needed,
    };
    let (Some(tag), Some(channels), Some(sample_rate), Some(block_align), Some(bits)) = (
        le16(body, 0),
        le16(body, 2),
        le32(body, 4),
        le16(body, 12),
        le16(body, 14),
    ) else {
        return Err(short(16));
    };
    let float = match tag {
        TAG_PCM => false,
        TAG_FLOAT => true,
        TAG_EXTENSIBLE => {
            // cbSize (16), valid bits (18), channel mask (20), sub-format GUID (24..40).
            let Some(guid) = array::<16>(body, 24) else {
                return Err(short(40));
            };
            let [t0, t1, tail @ ..] = guid;
            if tail != GUID_TAIL {
                return Err(WavError::UnsupportedSubformat { guid });
            }
            match u16::from_le_bytes([t0, t1]) {
                TAG_PCM => false,
                TAG_FLOAT => true,
                other => {
                    return Err(WavError::UnsupportedEncoding {
                        tag: other,
                        extensible: true,
                    })
                }
            }
        }
        other => {
            return Err(WavError::UnsupportedEncoding {
                tag: other,
                extensible: false,
            })
        }
    };
    let format = match (float, bits) {
        (false, 8) => SampleFormat::U8,
        (false, 16) => SampleFormat::I16,
        (false, 24) => SampleFormat::I24,
        (false, 32) => SampleFormat::I32,
        (true, 32) => SampleFormat::F32,
        (true, 64) => SampleFormat::F64,
        _ => return Err(WavError::UnsupportedBits { bits, float }),
    };
    if channels == 0 {
        return Err(WavError::ZeroChannels);
    }
    if sample_rate == 0 {
        return Err(WavError::ZeroSampleRate);
    }
    if u32::from(block_align) != u32::from(channels) * u32::from(bits / 8) {
        return Err(WavError::BlockAlignMismatch {
            block_align,
            channels,
            format,
        });
    }
    Ok(Fmt {
        format,
        channels,
        sample_rate,
    })
}

/// Whether four bytes at `at` look like a chunk identifier (printable ASCII).
fn plausible_id(bytes: &[u8], at: usize) -> bool {
    array::<4>(bytes, at).is_some_and(|id| id.iter().all(|b| (0x20..=0x7E).contains(b)))
}

/// Where the chunk after one ending at `end` starts. Chunks of odd size are followed by
/// a pad byte; a few writers forget it, so the pad is skipped unless the byte after it
/// cannot start a chunk identifier and `end` itself can.
fn next_chunk(bytes: &[u8], end: usize, size: u32) -> usize {
    let padded = end.saturating_add(1);
    if size % 2 == 0 || (!plausible_id(bytes, padded) && plausible_id(bytes, end)) {
        end
    } else {
        padded
    }
}

/// The `data` chunk as found.
struct Data<'a> {
    bytes: &'a [u8],
    declared: Option<u64>,
    truncated: bool,
}

/// A parsed WAV file, borrowing its sample data from the input.
///
/// Samples are stored interleaved: frame 0 (channel 0, channel 1, ...), frame 1, ...
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wav<'a> {
    format: SampleFormat,
    channels: u16,
    sample_rate: u32,
    data: &'a [u8],
    declared_data_len: Option<u64>,
    truncated: bool,
}

impl<'a> Wav<'a> {
    /// Parses a whole WAV file.
    ///
    /// Accepts 8, 16, 24 and 32-bit PCM and 32 and 64-bit float, plain or
    /// `WAVE_FORMAT_EXTENSIBLE`, any channel count and any non-zero sample rate. Never
    /// panics and allocates nothing.
    pub fn parse(bytes: &'a [u8]) -> Result<Self, WavError> {
        let short = || WavError::TooShort { len: bytes.len() };
        let magic = array::<4>(bytes, 0).ok_or_else(short)?;
        match &magic {
            b"RIFF" | b"RF64" | b"BW64" => {}
            b"RIFX" => return Err(WavError::BigEndian),
            _ => return Err(WavError::NotRiff { found: magic }),
        }
        let form = array::<4>(bytes, 8).ok_or_else(short)?;
        if &form != b"WAVE" {
            return Err(WavError::NotWave { found: form });
        }

        // The RIFF size is not trusted (streaming writers leave it 0 or 0xFFFFFFFF,
        // truncated files overstate it): chunks are walked to the end of the input.
        let mut pos = 12usize;
        let mut fmt_body: Option<&'a [u8]> = None;
        let mut data: Option<Data<'a>> = None;
        let mut ds64_data_len: Option<u64> = None;
        let mut cut: Option<WavError> = None;
        while fmt_body.is_none() || data.is_none() {
            let (Some(id), Some(size)) = (array::<4>(bytes, pos), le32(bytes, pos + 4)) else {
                break;
            };
            let start = pos + 8;
            let rest = bytes.get(start..).unwrap_or(&[]);
            if &id == b"data" && data.is_none() {
                // 0xFFFFFFFF: unknown (streamed) or, in RF64, given by the ds64 chunk.
                let declared = if size == u32::MAX {
                    ds64_data_len
                } else {
                    Some(u64::from(size))
                };
                match declared.and_then(|n| usize::try_from(n).ok()) {
                    Some(n) if n <= rest.len() => {
                        data = Some(Data {
                            bytes: rest.get(..n).unwrap_or(rest),
                            declared,
                            truncated: false,
                        });
                        // Only an RF64 size can exceed u32; then nothing useful follows.
                        let Ok(size32) = u32::try_from(n) else { break };
                        pos = next_chunk(bytes, start + n, size32);
                        continue;
                    }
                    _ => {
                        // Cut short, or of unknown length: everything left is samples.
                        data = Some(Data {
                            bytes: rest,
                            declared,
                            truncated: declared.is_some(),
                        });
                        break;
                    }
                }
            }
            let Some(body) = usize::try_from(size).ok().and_then(|n| rest.get(..n)) else {
                cut = Some(WavError::TruncatedChunk {
                    id,
                    offset: pos,
                    declared: size,
                    available: rest.len(),
                });
                break;
            };
            if &id == b"fmt " && fmt_body.is_none() {
                fmt_body = Some(body);
            } else if &id == b"ds64" {
                // RIFF size (0..8), data size (8..16), sample count, table.
                ds64_data_len = le64(body, 8);
            }
            pos = next_chunk(bytes, start + body.len(), size);
        }

        let fmt_body = fmt_body.ok_or_else(|| cut.clone().unwrap_or(WavError::NoFmtChunk))?;
        let fmt = parse_fmt(fmt_body)?;
        let data = data.ok_or_else(|| cut.unwrap_or(WavError::NoDataChunk))?;
        let frame = usize::from(fmt.channels) * fmt.format.bytes();
        let whole = data.bytes.len() - data.bytes.len() % frame;
        Ok(Wav {
            format: fmt.format,
            channels: fmt.channels,
            sample_rate: fmt.sample_rate,
            data: data.bytes.get(..whole).unwrap_or(&[]),
            declared_data_len: data.declared,
            truncated: data.truncated,
        })
    }

    /// How each sample is stored.
    pub fn format(&self) -> SampleFormat {
        self.format
    }

    /// Number of interleaved channels (at least 1).
    pub fn channels(&self) -> u16 {
        self.channels
    }

    /// Sample rate in Hz (frames per second) as declared by the file; never 0. The
    /// reader accepts any rate: range checks are the caller's.
    pub fn sample_rate(&self) -> u32 {
        self.sample_rate
    }

    /// Bytes per frame (one sample of every channel).
    pub fn frame_bytes(&self) -> usize {
        usize::from(self.channels) * self.format.bytes()
    }

    /// Number of whole frames present (samples per channel).
    pub fn frames(&self) -> usize {
        self.data.len() / self.frame_bytes().max(1)
    }

    /// Duration of the samples present, in seconds.
    pub fn duration_secs(&self) -> f64 {
        self.frames() as f64 / f64::from(self.sample_rate.max(1))
    }

    /// The raw interleaved sample bytes: whole frames only.
    pub fn data(&self) -> &'a [u8] {
        self.data
    }

    /// The `data` chunk's declared size in bytes, or `None` when the file does not say
    /// (size `0xFFFFFFFF`, see [`Wav::streamed`]).
    pub fn declared_data_len(&self) -> Option<u64> {
        self.declared_data_len
    }

    /// Whether the `data` chunk's declared size runs past the end of the file: the
    /// recording was cut short, and the samples present were taken.
    pub fn truncated(&self) -> bool {
        self.truncated
    }

    /// Whether the `data` chunk's size was `0xFFFFFFFF` (a streaming writer that could
    /// not go back to fill it in) and the samples were taken up to the end of the file.
    pub fn streamed(&self) -> bool {
        self.declared_data_len.is_none()
    }

    /// An iterator over one channel's samples as `f32`, full scale 1.0: `i16 / 32768`,
    /// `i24 / 8388608`, `i32 / 2147483648`, `(u8 - 128) / 128`; float samples as
    /// stored (rounded to `f32`).
    pub fn samples(&self, channel: u16) -> Result<Samples<'a>, WavError> {
        if channel >= self.channels {
            return Err(WavError::NoSuchChannel {
                channel,
                channels: self.channels,
            });
        }
        Ok(Samples {
            frames: self.data.chunks_exact(self.frame_bytes().max(1)),
            offset: usize::from(channel) * self.format.bytes(),
            format: self.format,
        })
    }

    /// One channel's samples as `f32`, scaled as by [`Wav::samples`]. Allocates one
    /// `f32` per frame present.
    pub fn channel(&self, channel: u16) -> Result<Vec<f32>, WavError> {
        Ok(self.samples(channel)?.collect())
    }
}

/// The samples of `channel` in `data`, interleaved frames of `channels` samples in
/// `format` (a block of a WAV file's data read on its own: whole frames; a partial
/// frame at the end is left out). For reading a file of any length in blocks.
pub fn samples_of(
    format: SampleFormat,
    channels: u16,
    channel: u16,
    data: &[u8],
) -> Result<Samples<'_>, WavError> {
    if channel >= channels {
        return Err(WavError::NoSuchChannel { channel, channels });
    }
    Ok(Samples {
        frames: data.chunks_exact((usize::from(channels) * format.bytes()).max(1)),
        offset: usize::from(channel) * format.bytes(),
        format,
    })
}

/// [`samples_of`] appended to `out`: the same samples, with one loop per format instead
/// of a dispatch per sample (several times faster for long files read in blocks).
pub fn extend_samples(
    format: SampleFormat,
    channels: u16,
    channel: u16,
    data: &[u8],
    out: &mut alloc::vec::Vec<f32>,
) -> Result<(), WavError> {
    if channel >= channels {
        return Err(WavError::NoSuchChannel { channel, channels });
    }
    let width = format.bytes();
    let frame = (usize::from(channels) * width).max(1);
    let offset = usize::from(channel) * width;
    let frames = data.chunks_exact(frame);
    out.reserve(frames.len());
    // Each arm is `decode` for one format.
    match format {
        SampleFormat::I16 if frame == 2 => out.extend(
            data.chunks_exact(2)
                .map(|b| f32::from(i16::from_le_bytes([b[0], b[1]])) / 32768.0),
        ),
        SampleFormat::I16 => out.extend(
            frames.map(|f| f32::from(i16::from_le_bytes([f[offset], f[offset + 1]])) / 32768.0),
        ),
        SampleFormat::F32 => {
            out.extend(frames.map(|f| {
                f32::from_le_bytes([f[offset], f[offset + 1], f[offset + 2], f[offset + 3]])
            }))
        }
        _ => out.extend(frames.map(|f| decode(format, &f[offset..]))),
    }
    Ok(())
}

/// Iterator over one channel of a [`Wav`], from [`Wav::samples`] or [`samples_of`].
#[derive(Debug, Clone)]
pub struct Samples<'a> {
    frames: ChunksExact<'a, u8>,
    offset: usize,
    format: SampleFormat,
}

impl Iterator for Samples<'_> {
    type Item = f32;

    fn next(&mut self) -> Option<f32> {
        let frame = self.frames.next()?;
        Some(decode(self.format, frame.get(self.offset..).unwrap_or(&[])))
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        self.frames.size_hint()
    }
}

impl ExactSizeIterator for Samples<'_> {}

impl FusedIterator for Samples<'_> {}

/// The sample at the start of `b`, scaled to full scale 1.0 (0.0 if `b` is too short,
/// which the callers rule out).
fn decode(format: SampleFormat, b: &[u8]) -> f32 {
    match (format, b) {
        (SampleFormat::U8, &[x, ..]) => (f32::from(x) - 128.0) / 128.0,
        (SampleFormat::I16, &[x0, x1, ..]) => f32::from(i16::from_le_bytes([x0, x1])) / 32768.0,
        (SampleFormat::I24, &[x0, x1, x2, ..]) => {
            // Place the 24 bits at the top of an i32 and shift back: sign extension.
            let v = i32::from_le_bytes([0, x0, x1, x2]) >> 8;
            v as f32 / 8_388_608.0
        }
        (SampleFormat::I32, &[x0, x1, x2, x3, ..]) => {
            (f64::from(i32::from_le_bytes([x0, x1, x2, x3])) / 2_147_483_648.0) as f32
        }
        (SampleFormat::F32, &[x0, x1, x2, x3, ..]) => f32::from_le_bytes([x0, x1, x2, x3]),
        (SampleFormat::F64, &[x0, x1, x2, x3, x4, x5, x6, x7, ..]) => {
            f64::from_le_bytes([x0, x1, x2, x3, x4, x5, x6, x7]) as f32
        }
        _ => 0.0,
    }
}

/// Sample encoding for [`write_mono`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum WriteFormat {
    /// 16-bit signed PCM (`WAVE_FORMAT_PCM`): samples are clipped to ±1.0, scaled by
    /// 32768 and rounded to nearest (halves away from zero); +1.0 becomes 32767, NaN
    /// becomes 0. Read by practically everything.
    #[default]
    Pcm16,
    /// 32-bit IEEE float (`WAVE_FORMAT_IEEE_FLOAT`, with a `fact` chunk): samples are
    /// stored exactly, without clipping.
    Float32,
}

/// One sample as 16-bit PCM: clipped to ±1.0, scaled by 32768, rounded.
fn to_i16(x: f32) -> i16 {
    // In f64 the scaled value and the half added for rounding are exact.
    let v = f64::from(x) * 32768.0;
    let r = if v >= 0.0 { v + 0.5 } else { v - 0.5 };
    // `as` truncates toward zero (so this rounds half away from zero), saturates on
    // overflow and maps NaN to 0.
    (r as i32).clamp(i32::from(i16::MIN), i32::from(i16::MAX)) as i16
}

/// Writes a mono WAV file: `samples` (full scale ±1.0) at `sample_rate` Hz.
///
/// The result is a minimal standard file: `RIFF`/`WAVE`, a `fmt ` chunk (16 bytes for
/// PCM; 18 bytes plus a `fact` chunk for float, as the format specification asks for
/// non-PCM data) and a `data` chunk.
///
/// Fails if `sample_rate` is 0 or too high for the byte rate to fit in 32 bits, or if
/// the data would exceed the 4 GiB a WAV file can describe.
pub fn write_mono(
    samples: &[f32],
    sample_rate: u32,
    format: WriteFormat,
) -> Result<Vec<u8>, WavError> {
    let (tag, sample_bytes, fmt_len) = match format {
        WriteFormat::Pcm16 => (TAG_PCM, 2u16, 16u32),
        WriteFormat::Float32 => (TAG_FLOAT, 4, 18),
    };
    let has_fact = format == WriteFormat::Float32;
    let byte_rate = sample_rate
        .checked_mul(u32::from(sample_bytes))
        .filter(|_| sample_rate > 0)
        .ok_or(WavError::WriteSampleRate { rate: sample_rate })?;
    // "WAVE" + fmt header and body + fact chunk + data header, then the samples.
    let riff_overhead = 4 + 8 + fmt_len + if has_fact { 12 } else { 0 } + 8;
    let too_long = WavError::WriteTooLong {
        samples: samples.len(),
    };
    let data_len = data_len(samples.len(), sample_bytes, riff_overhead).ok_or(too_long)?;
    let frames = u32::try_from(samples.len()).unwrap_or(u32::MAX);

    let total = len64(samples.len()) * u64::from(sample_bytes) + u64::from(riff_overhead) + 8;
    let mut out = Vec::with_capacity(usize::try_from(total).unwrap_or(0));
    out.extend_from_slice(b"RIFF");
    out.extend_from_slice(&(riff_overhead + data_len).to_le_bytes());
    out.extend_from_slice(b"WAVE");
    out.extend_from_slice(b"fmt ");
    out.extend_from_slice(&fmt_len.to_le_bytes());
    out.extend_from_slice(&tag.to_le_bytes());
    out.extend_from_slice(&1u16.to_le_bytes()); // channels
    out.extend_from_slice(&sample_rate.to_le_bytes());
    out.extend_from_slice(&byte_rate.to_le_bytes());
    out.extend_from_slice(&sample_bytes.to_le_bytes()); // block align
    out.extend_from_slice(&(sample_bytes * 8).to_le_bytes()); // bits per sample
    if has_fact {
        out.extend_from_slice(&0u16.to_le_bytes()); // cbSize: no extension
        out.extend_from_slice(b"fact");
        out.extend_from_slice(&4u32.to_le_bytes());
        out.extend_from_slice(&frames.to_le_bytes());
    }
    out.extend_from_slice(b"data");
    out.extend_from_slice(&data_len.to_le_bytes());
    match format {
        WriteFormat::Pcm16 => {
            for &x in samples {
                out.extend_from_slice(&to_i16(x).to_le_bytes());
            }
        }
        WriteFormat::Float32 => {
            for &x in samples {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
    }
    // Sample sizes are even, so the data chunk needs no pad byte.
    Ok(out)
}

/// Size of the data chunk for `samples` samples of `sample_bytes` bytes, if the RIFF
/// size (`riff_overhead` plus the data) fits in 32 bits.
fn data_len(samples: usize, sample_bytes: u16, riff_overhead: u32) -> Option<u32> {
    let n = len64(samples).checked_mul(u64::from(sample_bytes))?;
    let n = u32::try_from(n).ok()?;
    n.checked_add(riff_overhead).map(|_| n)
}

#[cfg(test)]
mod tests {
    extern crate std;

    use super::*;
    use alloc::string::ToString;
    use alloc::vec;
    use proptest::prelude::*;

    /// A chunk: identifier, size, body and the pad byte after an odd body.
    fn chunk(id: &[u8; 4], body: &[u8]) -> Vec<u8> {
        let mut c = id.to_vec();
        c.extend_from_slice(&(body.len() as u32).to_le_bytes());
        c.extend_from_slice(body);
        if body.len() % 2 == 1 {
            c.push(0);
        }
        c
    }

    /// A RIFF/WAVE file made of the given chunks.
    fn riff(chunks: &[Vec<u8>]) -> Vec<u8> {
        let body: Vec<u8> = chunks.concat();
        let mut f = b"RIFF".to_vec();
        f.extend_from_slice(&(4 + body.len() as u32).to_le_bytes());
        f.extend_from_slice(b"WAVE");
        f.extend_from_slice(&body);
        f
    }

    /// A 16-byte `fmt ` body with a consistent byte rate and block align.
    fn fmt_body(tag: u16, channels: u16, rate: u32, bits: u16) -> Vec<u8> {
        let align = channels * (bits / 8);
        let mut b = Vec::new();
        b.extend_from_slice(&tag.to_le_bytes());
        b.extend_from_slice(&channels.to_le_bytes());
        b.extend_from_slice(&rate.to_le_bytes());
        b.extend_from_slice(&(rate * u32::from(align)).to_le_bytes());
        b.extend_from_slice(&align.to_le_bytes());
        b.extend_from_slice(&bits.to_le_bytes());
        b
    }

    /// A 40-byte `WAVE_FORMAT_EXTENSIBLE` `fmt ` body.
    fn fmt_ext(channels: u16, rate: u32, bits: u16, valid: u16, sub: u16) -> Vec<u8> {
        let mut b = fmt_body(TAG_EXTENSIBLE, channels, rate, bits);
        b.extend_from_slice(&22u16.to_le_bytes());
        b.extend_from_slice(&valid.to_le_bytes());
        b.extend_from_slice(&0x4u32.to_le_bytes()); // front centre
        b.extend_from_slice(&sub.to_le_bytes());
        b.extend_from_slice(&GUID_TAIL);
        b
    }

    fn fmt(tag: u16, channels: u16, rate: u32, bits: u16) -> Vec<u8> {
        chunk(b"fmt ", &fmt_body(tag, channels, rate, bits))
    }

    fn parse_err(bytes: &[u8]) -> WavError {
        Wav::parse(bytes).expect_err("should not parse")
    }

    #[test]
    fn writer_pcm16_exact_bytes() {
        let out = write_mono(&[0.0, 1.0, -1.0, 0.5], 8000, WriteFormat::Pcm16).unwrap();
        let mut want = b"RIFF".to_vec();
        want.extend_from_slice(&(36u32 + 8).to_le_bytes());
        want.extend_from_slice(b"WAVE");
        want.extend_from_slice(&fmt(1, 1, 8000, 16));
        want.extend_from_slice(b"data");
        want.extend_from_slice(&8u32.to_le_bytes());
        for v in [0i16, 32767, -32768, 16384] {
            want.extend_from_slice(&v.to_le_bytes());
        }
        assert_eq!(out, want);
        assert_eq!(out.len(), 44 + 8);
    }

    #[test]
    fn writer_pcm16_round_trip() {
        let input: Vec<f32> = (0..1000)
            .map(|i| libm_free_sin(i as f32 * 0.01) * 0.9)
            .collect();
        let out = write_mono(&input, 48_000, WriteFormat::Pcm16).unwrap();
        let w = Wav::parse(&out).unwrap();
        assert_eq!(w.format(), SampleFormat::I16);
        assert_eq!(w.channels(), 1);
        assert_eq!(w.sample_rate(), 48_000);
        assert_eq!(w.frames(), 1000);
        assert!(!w.truncated() && !w.streamed());
        assert_eq!(w.declared_data_len(), Some(2000));
        let back = w.channel(0).unwrap();
        for (a, b) in input.iter().zip(&back) {
            assert!((a - b).abs() <= 0.5 / 32768.0 + 1e-9, "{a} vs {b}");
        }
        // Values on the 16-bit grid survive exactly.
        let grid: Vec<f32> = (-32768..32768)
            .step_by(7)
            .map(|v| v as f32 / 32768.0)
            .collect();
        let out = write_mono(&grid, 8000, WriteFormat::Pcm16).unwrap();
        assert_eq!(Wav::parse(&out).unwrap().channel(0).unwrap(), grid);
    }

    /// A cheap sine for test signals (no libm in this module).
    fn libm_free_sin(x: f32) -> f32 {
        let x = f64::from(x) % core::f64::consts::TAU;
        let mut term = x;
        let mut sum = 0.0;
        for n in 0..20 {
            sum += term;
            term *= -x * x / f64::from((2 * n + 2) * (2 * n + 3));
        }
        sum as f32
    }

    #[test]
    fn writer_pcm16_clips_and_rounds() {
        let step = 1.0 / 32768.0;
        let cases: [(f32, i16); 12] = [
            (1.0, 32767),
            (1.5, 32767),
            (f32::INFINITY, 32767),
            (-1.0, -32768),
            (-7.0, -32768),
            (f32::NEG_INFINITY, -32768),
            (f32::NAN, 0),
            (0.5 * step, 1),
            (-0.5 * step, -1),
            (0.499_999 * step, 0),
            (-0.499_999 * step, 0),
            (2.6 * step, 3),
        ];
        for (x, want) in cases {
            assert_eq!(to_i16(x), want, "{x}");
        }
        let out = write_mono(&[2.0, -2.0], 8000, WriteFormat::Pcm16).unwrap();
        let back = Wav::parse(&out).unwrap().channel(0).unwrap();
        assert_eq!(back, vec![32767.0 / 32768.0, -1.0]);
    }

    #[test]
    fn writer_float32_round_trip() {
        let input = [0.0f32, 1.0, -1.0, 0.123_456_79, 1.5, -3.25, 1e-20];
        let out = write_mono(&input, 96_000, WriteFormat::Float32).unwrap();
        // RIFF header, fmt (8 + 18), fact (12), data header.
        assert_eq!(out.len(), 12 + 26 + 12 + 8 + 4 * input.len());
        assert_eq!(&out[38..42], b"fact");
        assert_eq!(le32(&out, 46), Some(input.len() as u32));
        assert_eq!(le32(&out, 4), Some(out.len() as u32 - 8));
        let w = Wav::parse(&out).unwrap();
        assert_eq!(w.format(), SampleFormat::F32);
        assert_eq!(w.sample_rate(), 96_000);
        assert_eq!(w.channel(0).unwrap(), input);
    }

    #[test]
    fn writer_empty_and_errors() {
        for format in [WriteFormat::Pcm16, WriteFormat::Float32] {
            let out = write_mono(&[], 8000, format).unwrap();
            let w = Wav::parse(&out).unwrap();
            assert_eq!(w.frames(), 0);
            assert!(w.channel(0).unwrap().is_empty());
            assert_eq!(
                write_mono(&[0.0], 0, format),
                Err(WavError::WriteSampleRate { rate: 0 })
            );
            assert_eq!(
                write_mono(&[0.0], u32::MAX / 2 + 1, format),
                Err(WavError::WriteSampleRate {
                    rate: u32::MAX / 2 + 1
                })
            );
        }
        // The size limit, without allocating 4 GiB.
        assert_eq!(data_len(10, 2, 36), Some(20));
        assert_eq!(
            data_len((u32::MAX / 2 - 18) as usize, 2, 36),
            Some(u32::MAX - 37)
        );
        assert_eq!(data_len((u32::MAX / 2 - 17) as usize, 2, 36), None);
        assert_eq!(data_len(usize::MAX, 4, 50), None);
        let msg = WavError::WriteTooLong { samples: 3 }.to_string();
        assert!(msg.contains("4 GiB"), "{msg}");
    }

    #[test]
    fn reads_u8() {
        let f = riff(&[fmt(1, 1, 8000, 8), chunk(b"data", &[0, 128, 255, 64, 192])]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!(w.format(), SampleFormat::U8);
        assert_eq!(w.declared_data_len(), Some(5));
        assert_eq!(
            w.channel(0).unwrap(),
            vec![-1.0, 0.0, 127.0 / 128.0, -0.5, 0.5]
        );
    }

    #[test]
    fn reads_i24() {
        let vals = [-8_388_608i32, 0, 8_388_607, 4_194_304, -1, 1];
        let data: Vec<u8> = vals
            .iter()
            .flat_map(|v| v.to_le_bytes()[..3].to_vec())
            .collect();
        let f = riff(&[fmt(1, 1, 44_100, 24), chunk(b"data", &data)]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!(w.format(), SampleFormat::I24);
        let want: Vec<f32> = vals.iter().map(|&v| v as f32 / 8_388_608.0).collect();
        assert_eq!(w.channel(0).unwrap(), want);
        assert_eq!(w.channel(0).unwrap()[0], -1.0);
        assert_eq!(w.channel(0).unwrap()[3], 0.5);
    }

    #[test]
    fn reads_i32() {
        let vals = [i32::MIN, 0, i32::MAX, 1 << 30, -(1 << 29)];
        let data: Vec<u8> = vals.iter().flat_map(|v| v.to_le_bytes()).collect();
        let f = riff(&[fmt(1, 1, 192_000, 32), chunk(b"data", &data)]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!(w.format(), SampleFormat::I32);
        assert_eq!(w.sample_rate(), 192_000);
        assert_eq!(w.channel(0).unwrap(), vec![-1.0, 0.0, 1.0, 0.5, -0.25]);
    }

    #[test]
    fn reads_f64() {
        let vals = [0.25f64, -1.0, 1.0, 1e-3, -0.75];
        let data: Vec<u8> = vals.iter().flat_map(|v| v.to_le_bytes()).collect();
        let f = riff(&[
            fmt(3, 1, 22_050, 64),
            chunk(b"fact", &5u32.to_le_bytes()),
            chunk(b"data", &data),
        ]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!(w.format(), SampleFormat::F64);
        let want: Vec<f32> = vals.iter().map(|&v| v as f32).collect();
        assert_eq!(w.channel(0).unwrap(), want);
    }

    #[test]
    fn reads_f32_with_18_byte_fmt() {
        let mut body = fmt_body(3, 1, 8000, 32);
        body.extend_from_slice(&0u16.to_le_bytes());
        let data: Vec<u8> = [0.5f32, -0.5]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let f = riff(&[chunk(b"fmt ", &body), chunk(b"data", &data)]);
        assert_eq!(Wav::parse(&f).unwrap().channel(0).unwrap(), vec![0.5, -0.5]);
    }

    #[test]
    fn reads_extensible() {
        // 16-bit PCM.
        let data: Vec<u8> = [-16384i16, 16384]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let f = riff(&[
            chunk(b"fmt ", &fmt_ext(1, 8000, 16, 16, TAG_PCM)),
            chunk(b"data", &data),
        ]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!(w.format(), SampleFormat::I16);
        assert_eq!(w.channel(0).unwrap(), vec![-0.5, 0.5]);

        // 24 valid bits in a 32-bit container: left-justified, read as I32.
        let data: Vec<u8> = [0x4000_0000i32, -0x2000_0000]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let f = riff(&[
            chunk(b"fmt ", &fmt_ext(1, 48_000, 32, 24, TAG_PCM)),
            chunk(b"data", &data),
        ]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!(w.format(), SampleFormat::I32);
        assert_eq!(w.channel(0).unwrap(), vec![0.5, -0.25]);

        // Packed 24-bit, stereo.
        let data = [0, 0, 0x40, 0, 0, 0xC0, 0xFF, 0xFF, 0x7F, 0, 0, 0x80];
        let f = riff(&[
            chunk(b"fmt ", &fmt_ext(2, 96_000, 24, 24, TAG_PCM)),
            chunk(b"data", &data),
        ]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!(
            (w.format(), w.channels(), w.frames()),
            (SampleFormat::I24, 2, 2)
        );
        assert_eq!(w.channel(0).unwrap(), vec![0.5, 8_388_607.0 / 8_388_608.0]);
        assert_eq!(w.channel(1).unwrap(), vec![-0.5, -1.0]);

        // 32 and 64-bit float.
        let data: Vec<u8> = [0.25f32, -2.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let f = riff(&[
            chunk(b"fmt ", &fmt_ext(1, 8000, 32, 32, TAG_FLOAT)),
            chunk(b"data", &data),
        ]);
        assert_eq!(
            Wav::parse(&f).unwrap().channel(0).unwrap(),
            vec![0.25, -2.0]
        );
        let data: Vec<u8> = [0.125f64].iter().flat_map(|v| v.to_le_bytes()).collect();
        let f = riff(&[
            chunk(b"fmt ", &fmt_ext(1, 8000, 64, 64, TAG_FLOAT)),
            chunk(b"data", &data),
        ]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!(w.format(), SampleFormat::F64);
        assert_eq!(w.channel(0).unwrap(), vec![0.125]);
    }

    #[test]
    fn multi_channel_pick_one() {
        // Three channels of 16-bit: frame k is (k, -k, 1000 + k) / 32768.
        let mut data = Vec::new();
        for k in 0..10i16 {
            for v in [k, -k, 1000 + k] {
                data.extend_from_slice(&v.to_le_bytes());
            }
        }
        let f = riff(&[fmt(1, 3, 16_000, 16), chunk(b"data", &data)]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!((w.channels(), w.frames(), w.frame_bytes()), (3, 10, 6));
        assert!((w.duration_secs() - 10.0 / 16_000.0).abs() < 1e-12);
        for ch in 0..3u16 {
            let got = w.channel(ch).unwrap();
            let want: Vec<f32> = (0..10i16)
                .map(|k| f32::from([k, -k, 1000 + k][usize::from(ch)]) / 32768.0)
                .collect();
            assert_eq!(got, want);
            assert_eq!(w.samples(ch).unwrap().len(), 10);
        }
        let e = w.channel(3).unwrap_err();
        assert_eq!(
            e,
            WavError::NoSuchChannel {
                channel: 3,
                channels: 3
            }
        );
        assert!(e.to_string().contains("no channel 3"), "{e}");
        assert!(w.samples(u16::MAX).is_err());
    }

    #[test]
    fn skips_unknown_chunks_and_odd_padding() {
        let samples: Vec<u8> = [1000i16, -1000]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        // Odd chunks before and between fmt and data, each followed by its pad byte.
        let f = riff(&[
            chunk(b"JUNK", &[0xAA; 27]),
            fmt(1, 1, 8000, 16),
            chunk(b"LIST", b"INFOISFT\x05\x00\x00\x00sox!\x00"),
            chunk(b"fact", &2u32.to_le_bytes()),
            chunk(b"odd ", &[1]),
            chunk(b"data", &samples),
            chunk(b"LIST", &[1, 2, 3]),
        ]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!(
            w.channel(0).unwrap(),
            vec![1000.0 / 32768.0, -1000.0 / 32768.0]
        );
        assert!(!w.truncated());
    }

    #[test]
    fn odd_data_chunk_then_fmt() {
        // 8-bit data of odd length, its pad byte, and the fmt chunk after it.
        let f = riff(&[chunk(b"data", &[128, 255, 0]), fmt(1, 1, 11_025, 8)]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!(w.sample_rate(), 11_025);
        assert_eq!(w.channel(0).unwrap(), vec![0.0, 127.0 / 128.0, -1.0]);
    }

    #[test]
    fn missing_pad_byte_is_tolerated() {
        let samples = [0u8, 0x40];
        let mut f = riff(&[fmt(1, 1, 8000, 16)]);
        // An odd chunk written without its pad byte, then the data chunk.
        f.extend_from_slice(b"LIST");
        f.extend_from_slice(&3u32.to_le_bytes());
        f.extend_from_slice(&[1, 2, 3]);
        f.extend_from_slice(&chunk(b"data", &samples));
        let w = Wav::parse(&f).unwrap();
        assert_eq!(w.channel(0).unwrap(), vec![0.5]);
    }

    #[test]
    fn truncated_data() {
        let mut data = Vec::new();
        for v in [100i16, 200, 300] {
            data.extend_from_slice(&v.to_le_bytes());
        }
        let mut f = riff(&[fmt(1, 1, 8000, 16)]);
        f.extend_from_slice(b"data");
        f.extend_from_slice(&1000u32.to_le_bytes());
        f.extend_from_slice(&data);
        f.push(0x12); // half a sample
        let w = Wav::parse(&f).unwrap();
        assert!(w.truncated());
        assert!(!w.streamed());
        assert_eq!(w.declared_data_len(), Some(1000));
        assert_eq!(w.frames(), 3);
        assert_eq!(w.data().len(), 6);
        assert_eq!(
            w.channel(0).unwrap(),
            vec![100.0 / 32768.0, 200.0 / 32768.0, 300.0 / 32768.0]
        );

        // Stereo cut in the middle of a frame: the partial frame is dropped.
        let mut f = riff(&[fmt(1, 2, 8000, 16)]);
        f.extend_from_slice(b"data");
        f.extend_from_slice(&400u32.to_le_bytes());
        f.extend_from_slice(&[0, 0x40, 0, 0xC0, 0, 0x20]);
        let w = Wav::parse(&f).unwrap();
        assert!(w.truncated());
        assert_eq!(w.frames(), 1);
        assert_eq!(w.channel(1).unwrap(), vec![-0.5]);

        // Header only, data chunk cut off right after its size.
        let mut f = riff(&[fmt(1, 1, 8000, 16)]);
        f.extend_from_slice(b"data");
        f.extend_from_slice(&400u32.to_le_bytes());
        let w = Wav::parse(&f).unwrap();
        assert!(w.truncated());
        assert_eq!(w.frames(), 0);
    }

    #[test]
    fn data_size_not_a_whole_number_of_frames() {
        let f = riff(&[fmt(1, 1, 8000, 16), chunk(b"data", &[0, 0x40, 0])]);
        let w = Wav::parse(&f).unwrap();
        assert!(!w.truncated());
        assert_eq!(w.channel(0).unwrap(), vec![0.5]);
    }

    #[test]
    fn streamed_data() {
        let mut f = b"RIFF".to_vec();
        f.extend_from_slice(&u32::MAX.to_le_bytes());
        f.extend_from_slice(b"WAVE");
        f.extend_from_slice(&fmt(1, 1, 8000, 16));
        f.extend_from_slice(b"data");
        f.extend_from_slice(&u32::MAX.to_le_bytes());
        f.extend_from_slice(&[0, 0x40, 0, 0xC0]);
        let w = Wav::parse(&f).unwrap();
        assert!(w.streamed());
        assert!(!w.truncated());
        assert_eq!(w.declared_data_len(), None);
        assert_eq!(w.channel(0).unwrap(), vec![0.5, -0.5]);
    }

    #[test]
    fn rf64_with_ds64() {
        let mut ds64 = Vec::new();
        ds64.extend_from_slice(&0u64.to_le_bytes()); // RIFF size (unused)
        ds64.extend_from_slice(&4u64.to_le_bytes()); // data size
        ds64.extend_from_slice(&2u64.to_le_bytes()); // sample count
        ds64.extend_from_slice(&0u32.to_le_bytes()); // table length
        let mut f = b"RF64".to_vec();
        f.extend_from_slice(&u32::MAX.to_le_bytes());
        f.extend_from_slice(b"WAVE");
        f.extend_from_slice(&chunk(b"ds64", &ds64));
        f.extend_from_slice(&fmt(1, 1, 8000, 16));
        f.extend_from_slice(b"data");
        f.extend_from_slice(&u32::MAX.to_le_bytes());
        f.extend_from_slice(&[0, 0x40, 0, 0xC0]);
        f.extend_from_slice(&chunk(b"LIST", b"trailing"));
        let w = Wav::parse(&f).unwrap();
        assert!(!w.streamed() && !w.truncated());
        assert_eq!(w.declared_data_len(), Some(4));
        assert_eq!(w.channel(0).unwrap(), vec![0.5, -0.5]);
    }

    #[test]
    fn first_fmt_and_data_win() {
        let f = riff(&[
            fmt(1, 1, 8000, 16),
            chunk(b"data", &[0, 0x40]),
            fmt(1, 1, 16_000, 8),
            chunk(b"data", &[0, 0]),
        ]);
        let w = Wav::parse(&f).unwrap();
        assert_eq!(w.sample_rate(), 8000);
        assert_eq!(w.channel(0).unwrap(), vec![0.5]);
    }

    #[test]
    fn error_not_riff() {
        let e = parse_err(b"OggS\0\x02\0\0\0\0\0\0\0\0");
        assert_eq!(e, WavError::NotRiff { found: *b"OggS" });
        let msg = e.to_string();
        assert!(
            msg.starts_with("not a WAV file: the first 4 bytes are 'OggS', expected 'RIFF'"),
            "{msg}"
        );
        assert!(msg.contains("Ogg"), "{msg}");
        let e = parse_err(b"\0\x01'\\junkjunk");
        assert_eq!(
            e.to_string(),
            "not a WAV file: the first 4 bytes are '\\x00\\x01\\x27\\x5C', expected 'RIFF'"
        );
        assert!(parse_err(b"ID3\x04aaaaaaaaa").to_string().contains("MP3"));
    }

    #[test]
    fn error_too_short() {
        for len in 0..12 {
            let mut f = b"RIFF\x04\0\0\0WAVE".to_vec();
            f.truncate(len);
            let e = parse_err(&f);
            assert_eq!(e, WavError::TooShort { len });
            assert!(e.to_string().contains(&alloc::format!("only {len} bytes")));
        }
        // Garbage that is too short is still named for its first bytes.
        assert_eq!(parse_err(b"GIF89a"), WavError::NotRiff { found: *b"GIF8" });
    }

    #[test]
    fn error_big_endian_and_not_wave() {
        let e = parse_err(b"RIFX\x04\0\0\0WAVE");
        assert_eq!(e, WavError::BigEndian);
        assert!(e.to_string().contains("big-endian"));
        let e = parse_err(b"RIFF\x04\0\0\0AVI ");
        assert_eq!(e, WavError::NotWave { found: *b"AVI " });
        assert!(e.to_string().contains("'AVI '"), "{e}");
    }

    #[test]
    fn error_no_fmt_no_data() {
        let e = parse_err(&riff(&[chunk(b"data", &[0, 0])]));
        assert_eq!(e, WavError::NoFmtChunk);
        assert!(e.to_string().starts_with("no 'fmt ' chunk"));
        let e = parse_err(&riff(&[]));
        assert_eq!(e, WavError::NoFmtChunk);
        let e = parse_err(&riff(&[fmt(1, 1, 8000, 16), chunk(b"LIST", b"ab")]));
        assert_eq!(e, WavError::NoDataChunk);
        assert!(e.to_string().starts_with("no 'data' chunk"));
        // A dangling partial chunk header at the end is ignored.
        let mut f = riff(&[fmt(1, 1, 8000, 16)]);
        f.extend_from_slice(b"dat");
        assert_eq!(parse_err(&f), WavError::NoDataChunk);
    }

    #[test]
    fn error_truncated_chunk() {
        let mut f = riff(&[fmt(1, 1, 8000, 16)]);
        f.extend_from_slice(b"LIST");
        f.extend_from_slice(&100u32.to_le_bytes());
        f.extend_from_slice(b"INFO");
        let e = parse_err(&f);
        assert_eq!(
            e,
            WavError::TruncatedChunk {
                id: *b"LIST",
                offset: 36,
                declared: 100,
                available: 4
            }
        );
        let msg = e.to_string();
        assert!(msg.contains("'LIST'") && msg.contains("truncated"), "{msg}");
        // A cut fmt chunk.
        let mut f = riff(&[]);
        f.extend_from_slice(b"fmt ");
        f.extend_from_slice(&16u32.to_le_bytes());
        f.extend_from_slice(&[1, 0, 1, 0]);
        assert!(matches!(
            parse_err(&f),
            WavError::TruncatedChunk { id, .. } if &id == b"fmt "
        ));
    }

    #[test]
    fn error_fmt_too_short() {
        let f = riff(&[chunk(b"fmt ", &[1, 0, 1, 0]), chunk(b"data", &[])]);
        let e = parse_err(&f);
        assert_eq!(e, WavError::FmtTooShort { len: 4, needed: 16 });
        assert!(e.to_string().contains("at least 16"));
        let mut body = fmt_ext(1, 8000, 16, 16, TAG_PCM);
        body.truncate(30);
        let e = parse_err(&riff(&[chunk(b"fmt ", &body), chunk(b"data", &[])]));
        assert_eq!(
            e,
            WavError::FmtTooShort {
                len: 30,
                needed: 40
            }
        );
    }

    #[test]
    fn error_unsupported_encoding() {
        let e = parse_err(&riff(&[fmt(7, 1, 8000, 8), chunk(b"data", &[0])]));
        assert_eq!(
            e,
            WavError::UnsupportedEncoding {
                tag: 7,
                extensible: false
            }
        );
        let msg = e.to_string();
        assert!(
            msg.starts_with("unsupported encoding: mu-law (format tag 0x0007)"),
            "{msg}"
        );
        let e = parse_err(&riff(&[fmt(0x55, 1, 8000, 16), chunk(b"data", &[])]));
        assert!(e.to_string().contains("MP3"));
        let e = parse_err(&riff(&[
            chunk(b"fmt ", &fmt_ext(1, 8000, 8, 8, 6)),
            chunk(b"data", &[0]),
        ]));
        assert_eq!(
            e,
            WavError::UnsupportedEncoding {
                tag: 6,
                extensible: true
            }
        );
        assert!(e.to_string().contains("A-law") && e.to_string().contains("EXTENSIBLE"));
    }

    #[test]
    fn error_unsupported_subformat() {
        let mut body = fmt_ext(1, 8000, 16, 16, TAG_PCM);
        body[30] = 0x77; // not the standard GUID tail any more
        let e = parse_err(&riff(&[chunk(b"fmt ", &body), chunk(b"data", &[])]));
        let WavError::UnsupportedSubformat { guid } = e else {
            panic!("{e:?}");
        };
        assert_eq!(guid[6], 0x77);
        assert_eq!(
            e.to_string(),
            "unsupported encoding: WAVE_FORMAT_EXTENSIBLE sub-format \
             {00000001-0000-0077-8000-00AA00389B71}; only the PCM and IEEE float \
             sub-formats are read: convert it (for example \
             `sox in.wav -e signed-integer -b 16 out.wav`)"
        );
    }

    #[test]
    fn error_unsupported_bits() {
        let e = parse_err(&riff(&[fmt(1, 1, 8000, 12), chunk(b"data", &[])]));
        assert_eq!(
            e,
            WavError::UnsupportedBits {
                bits: 12,
                float: false
            }
        );
        assert_eq!(
            e.to_string(),
            "unsupported sample format: 12-bit PCM; use 8, 16, 24 or 32-bit PCM or \
             32/64-bit float"
        );
        let e = parse_err(&riff(&[fmt(3, 1, 8000, 16), chunk(b"data", &[])]));
        assert_eq!(
            e,
            WavError::UnsupportedBits {
                bits: 16,
                float: true
            }
        );
        assert!(e.to_string().contains("16-bit float"));
        let e = parse_err(&riff(&[
            chunk(b"fmt ", &fmt_ext(1, 8000, 20, 20, TAG_PCM)),
            chunk(b"data", &[]),
        ]));
        assert_eq!(
            e,
            WavError::UnsupportedBits {
                bits: 20,
                float: false
            }
        );
    }

    #[test]
    fn error_zero_channels_zero_rate_block_align() {
        let e = parse_err(&riff(&[fmt(1, 0, 8000, 16), chunk(b"data", &[])]));
        assert_eq!(e, WavError::ZeroChannels);
        assert!(e.to_string().contains("0 channels"));
        let e = parse_err(&riff(&[fmt(1, 1, 0, 16), chunk(b"data", &[])]));
        assert_eq!(e, WavError::ZeroSampleRate);
        assert!(e.to_string().contains("0 Hz"));
        let mut body = fmt_body(1, 2, 8000, 16);
        body[12] = 2; // block align 2, but two 16-bit channels need 4
        let e = parse_err(&riff(&[chunk(b"fmt ", &body), chunk(b"data", &[])]));
        assert_eq!(
            e,
            WavError::BlockAlignMismatch {
                block_align: 2,
                channels: 2,
                format: SampleFormat::I16
            }
        );
        let msg = e.to_string();
        assert!(
            msg.contains("2 bytes per frame") && msg.contains("16-bit PCM take 4 bytes"),
            "{msg}"
        );
    }

    #[test]
    fn any_sample_rate_is_reported() {
        for rate in [1u32, 4000, 7999, 8000, 44_100, 192_000, 192_001, u32::MAX] {
            let f = riff(&[fmt(1, 1, rate, 8), chunk(b"data", &[128])]);
            assert_eq!(Wav::parse(&f).unwrap().sample_rate(), rate);
        }
    }

    #[test]
    fn sample_format_display() {
        assert_eq!(SampleFormat::U8.to_string(), "8-bit PCM");
        assert_eq!(SampleFormat::I24.to_string(), "24-bit PCM");
        assert_eq!(SampleFormat::F64.to_string(), "64-bit float");
        for f in [
            SampleFormat::U8,
            SampleFormat::I16,
            SampleFormat::I24,
            SampleFormat::I32,
            SampleFormat::F32,
            SampleFormat::F64,
        ] {
            assert_eq!(usize::from(f.bits() / 8), f.bytes());
        }
    }

    /// A few valid files for the mutation property below.
    fn seeds() -> Vec<Vec<u8>> {
        vec![
            write_mono(&[0.1, -0.2, 0.3], 8000, WriteFormat::Pcm16).unwrap(),
            write_mono(&[0.1, -0.2, 0.3], 8000, WriteFormat::Float32).unwrap(),
            riff(&[
                chunk(b"LIST", b"abc"),
                chunk(b"fmt ", &fmt_ext(3, 48_000, 24, 24, TAG_PCM)),
                chunk(b"data", &[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13]),
            ]),
            riff(&[fmt(1, 2, 8000, 8), chunk(b"data", &[1, 2, 3])]),
        ]
    }

    /// Checks the invariants of a successful parse.
    fn check(bytes: &[u8]) -> Result<(), TestCaseError> {
        match Wav::parse(bytes) {
            Ok(w) => {
                prop_assert!(w.channels() > 0 && w.sample_rate() > 0);
                prop_assert!(w.data().len() <= bytes.len());
                prop_assert_eq!(w.data().len(), w.frames() * w.frame_bytes());
                for ch in 0..w.channels().min(4) {
                    prop_assert_eq!(w.channel(ch).unwrap().len(), w.frames());
                }
                prop_assert!(w.channel(w.channels()).is_err());
            }
            Err(e) => prop_assert!(!e.to_string().is_empty()),
        }
        Ok(())
    }

    proptest! {
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
            check(&bytes)?;
        }

        #[test]
        fn arbitrary_chunks_after_header_never_panic(
            tail in proptest::collection::vec(any::<u8>(), 0..256),
        ) {
            let mut f = b"RIFF\xFF\xFF\xFF\xFFWAVE".to_vec();
            f.extend_from_slice(&tail);
            check(&f)?;
        }

        #[test]
        fn mutated_valid_files_never_panic(
            seed in 0usize..4,
            edits in proptest::collection::vec((any::<usize>(), any::<u8>()), 0..8),
            cut in any::<usize>(),
        ) {
            let mut f = seeds().swap_remove(seed);
            for (at, b) in edits {
                let n = f.len();
                f[at % n] = b;
            }
            let n = f.len();
            f.truncate(cut % (n + 1));
            check(&f)?;
        }

        #[test]
        fn pcm16_round_trip_within_half_a_step(
            input in proptest::collection::vec(-1.0f32..=1.0, 0..64),
            rate in 1u32..1_000_000,
        ) {
            let out = write_mono(&input, rate, WriteFormat::Pcm16).unwrap();
            let w = Wav::parse(&out).unwrap();
            prop_assert_eq!(w.sample_rate(), rate);
            let back = w.channel(0).unwrap();
            prop_assert_eq!(back.len(), input.len());
            for (a, b) in input.iter().zip(&back) {
                let limit = if *a >= 32767.0 / 32768.0 { 1.0 / 32768.0 } else { 0.5 / 32768.0 };
                prop_assert!((a - b).abs() <= limit, "{} vs {}", a, b);
            }
        }

        #[test]
        fn float32_round_trip_exact(
            input in proptest::collection::vec(any::<f32>(), 0..64),
        ) {
            let out = write_mono(&input, 8000, WriteFormat::Float32).unwrap();
            let back = Wav::parse(&out).unwrap().channel(0).unwrap();
            prop_assert_eq!(back.len(), input.len());
            for (a, b) in input.iter().zip(&back) {
                prop_assert_eq!(a.to_bits(), b.to_bits());
            }
        }
    }
}
