//! AES-CCM* as WirelessHART uses it: a 4-byte MIC (M = 4), a 13-byte nonce, AES-128
//! from RustCrypto's `aes` and `ccm` crates (no block cipher is written here).
//!
//! CCM* with M = 4 is CCM with a 4-byte tag; the data-link MIC authenticates without
//! encrypting (CCM over an empty plaintext), the network layer encrypts its payload.

use aes::Aes128;
use ccm::aead::generic_array::GenericArray;
use ccm::aead::{AeadInPlace, KeyInit};
use ccm::consts::{U13, U4};

type Cipher = ccm::Ccm<Aes128, U4, U13>;

/// A 128-bit AES key.
pub type Key = [u8; 16];

/// The well-known data-link key: the ASCII bytes `www.hartcomm.org`. Advertisements
/// and the frames of a joining device are authenticated with it.
pub const WELL_KNOWN_KEY: Key = *b"www.hartcomm.org";

/// The 4-byte MIC over `aad` with nothing encrypted (the data-link MIC).
pub fn mic(key: &Key, nonce: &[u8; 13], aad: &[u8]) -> [u8; 4] {
    let c = Cipher::new(GenericArray::from_slice(key));
    let tag = c
        .encrypt_in_place_detached(GenericArray::from_slice(nonce), aad, &mut [])
        .unwrap_or_default();
    tag.into()
}

/// Encrypts `data` in place and returns its 4-byte MIC.
pub fn encrypt(key: &Key, nonce: &[u8; 13], aad: &[u8], data: &mut [u8]) -> [u8; 4] {
    let c = Cipher::new(GenericArray::from_slice(key));
    c.encrypt_in_place_detached(GenericArray::from_slice(nonce), aad, data)
        .unwrap_or_default()
        .into()
}

/// Decrypts `data` in place when `mic` verifies; `false` (and `data` unchanged in
/// meaning: treat it as garbage) when the key, nonce or data are wrong.
pub fn decrypt(key: &Key, nonce: &[u8; 13], aad: &[u8], data: &mut [u8], mic: &[u8; 4]) -> bool {
    let c = Cipher::new(GenericArray::from_slice(key));
    c.decrypt_in_place_detached(
        GenericArray::from_slice(nonce),
        aad,
        data,
        GenericArray::from_slice(mic),
    )
    .is_ok()
}

/// Parses 32 hex digits into a key (spaces and colons between bytes allowed).
pub fn parse_key(text: &str) -> Option<Key> {
    let mut k = [0u8; 16];
    (hart_proto::wire::hex_into(text.trim(), &mut k)? == 16).then_some(k)
}
