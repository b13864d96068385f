//! The rules of a request's PDU that Modbus TCP's and RTU's framings both check before
//! anything decodes it.

/// The quantity and byte-count rules of functions 15, 16 and 23 (Modbus application
/// protocol 1.1b3, 6.11, 6.12, 6.17).
pub(crate) fn check_request_pdu(pdu: &[u8]) -> Result<(), &'static str> {
    let u16_at = |i: usize| pdu.get(i..i + 2).map(|b| u16::from_be_bytes([b[0], b[1]]));
    let byte = |i: usize| pdu.get(i).copied().map(usize::from);
    match pdu.first() {
        Some(0x0F) => match (u16_at(3), byte(5)) {
            (Some(q), Some(n)) if (1..=1968).contains(&q) && n == usize::from(q).div_ceil(8) => {
                Ok(())
            }
            _ => Err("write multiple coils: quantity outside 1-1968 or byte count wrong"),
        },
        Some(0x10) => match (u16_at(3), byte(5)) {
            (Some(q), Some(n)) if (1..=123).contains(&q) && n == 2 * usize::from(q) => Ok(()),
            _ => Err("write multiple registers: quantity outside 1-123 or byte count wrong"),
        },
        Some(0x17) => match (u16_at(3), u16_at(7), byte(9)) {
            (Some(r), Some(w), Some(n))
                if (1..=125).contains(&r) && (1..=121).contains(&w) && n == 2 * usize::from(w) =>
            {
                Ok(())
            }
            _ => Err(
                "read/write multiple registers: quantities outside the limits or byte count wrong",
            ),
        },
        _ => Ok(()),
    }
}
