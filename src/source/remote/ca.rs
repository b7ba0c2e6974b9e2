//! Extra certificate authorities ([`super::RemoteOptions::ca_file`]): a PEM file read once,
//! trusted for `https://` and S3 endpoints besides the system's roots (a private CA, or a test
//! server's own). Each backend turns the bytes into its client's certificates.

use std::path::Path;

/// The PEM bytes of `path`, refused (naming the variable, the file and what was expected)
/// when it cannot be read or holds no certificate.
pub(crate) fn read(path: &Path) -> Result<Vec<u8>, String> {
    let shown = path.display();
    let pem = std::fs::read(path).map_err(|e| {
        format!("CLIPMAP_REMOTE_CA_FILE {shown}: cannot read it ({e}); name a readable PEM file of CA certificates, or unset the variable")
    })?;
    if !pem.windows(CERT.len()).any(|w| w == CERT) {
        return Err(format!(
            "CLIPMAP_REMOTE_CA_FILE {shown}: found no PEM certificate (a `{}` line) in its {} bytes; expected one or more CA certificates in PEM",
            String::from_utf8_lossy(CERT),
            pem.len()
        ));
    }
    Ok(pem)
}

const CERT: &[u8] = b"-----BEGIN CERTIFICATE-----";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ca_file_must_exist_and_hold_a_certificate() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("none.pem");
        let e = read(&missing).unwrap_err();
        assert!(e.starts_with("CLIPMAP_REMOTE_CA_FILE") && e.contains("none.pem") && e.contains("cannot read"), "{e}");
        let key = dir.path().join("key.pem");
        std::fs::write(&key, "-----BEGIN PRIVATE KEY-----\nAAAA\n-----END PRIVATE KEY-----\n").unwrap();
        let e = read(&key).unwrap_err();
        assert!(e.contains("key.pem") && e.contains("no PEM certificate") && e.contains("BEGIN CERTIFICATE"), "{e}");
        let ca = dir.path().join("ca.pem");
        std::fs::write(&ca, "-----BEGIN CERTIFICATE-----\nAAAA\n-----END CERTIFICATE-----\n").unwrap();
        assert!(read(&ca).unwrap().starts_with(CERT));
    }
}
