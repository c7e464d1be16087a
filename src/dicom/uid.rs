//! DICOM UIDs under the 2.25 root (ISO/IEC 9834-8): random ones for new studies, and ones derived
//! from a parent UID and a name, so that every writer of a series agrees without shared state.

use sha2::{Digest, Sha256};

/// A DICOM UID under the 2.25 root (ISO/IEC 9834-8): a random 128-bit number in decimal.
pub fn new_uid() -> String {
    let mut bytes = [0u8; 16];
    let random = std::fs::File::open("/dev/urandom")
        .and_then(|mut f| std::io::Read::read_exact(&mut f, &mut bytes));
    if random.is_err() {
        // Without /dev/urandom: time and pid still make collisions vanishingly unlikely here.
        let nanos = chrono::Utc::now().timestamp_nanos_opt().unwrap_or_default() as u128;
        bytes = (nanos ^ ((std::process::id() as u128) << 64)).to_le_bytes();
    }
    format!("2.25.{}", u128::from_le_bytes(bytes))
}

/// A UID under 2.25 from a name-based hash (like a version-5 UUID): stable for the same inputs.
pub fn derived_uid(parent: &str, name: &str) -> String {
    let digest = Sha256::digest(format!("{parent}/{name}").as_bytes());
    let mut bytes = [0u8; 16];
    bytes.copy_from_slice(&digest[..16]);
    // Set the UUID version (5) and variant bits so the number is a well-formed UUID.
    bytes[6] = (bytes[6] & 0x0f) | 0x50;
    bytes[8] = (bytes[8] & 0x3f) | 0x80;
    format!("2.25.{}", u128::from_be_bytes(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn derived_uids_are_stable_valid_and_distinct() {
        let a = derived_uid("2.25.1", "post_top");
        assert_eq!(a, derived_uid("2.25.1", "post_top"));
        assert_ne!(a, derived_uid("2.25.1", "pre_top"));
        assert!(a.len() <= 64 && a.starts_with("2.25.") && !a[5..].starts_with('0'));
        assert!(a[5..].chars().all(|c| c.is_ascii_digit()));
    }
}
