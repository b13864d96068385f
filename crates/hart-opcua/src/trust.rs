//! The trust list of client certificates, as OPC UA servers keep it: a client's
//! certificate is trusted only when it is in `<pki>/trusted`; an unknown one is refused
//! and lands in `<pki>/rejected` (async-opcua writes it there, named
//! `<common name> [<thumbprint>].der`), where an operator looks at it and moves it to
//! `trusted` ([`trust`], `hartkit opcua trust`). The server reads both folders at each
//! connection, so a certificate trusted while it runs is accepted at the client's next
//! attempt.

use std::path::{Path, PathBuf};

use opcua::crypto::{CertificateStore, X509};

/// A certificate found in, or put into, the PKI directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CertInfo {
    /// Its file.
    pub path: PathBuf,
    /// Its subject (`CN=...`).
    pub subject: String,
    /// Its SHA-1 thumbprint, lowercase hex (as OPC UA and the file names show it).
    pub thumbprint: String,
    /// The end of its validity (UTC), when readable.
    pub not_after: Option<String>,
}

/// The client certificates of a PKI directory.
#[derive(Debug, Clone, Default)]
pub struct Certificates {
    /// `<pki>/rejected`.
    pub rejected_dir: PathBuf,
    /// `<pki>/trusted`.
    pub trusted_dir: PathBuf,
    /// Certificates refused so far, waiting for an operator.
    pub rejected: Vec<CertInfo>,
    /// Certificates of the clients let in.
    pub trusted: Vec<CertInfo>,
    /// Files in either folder that are no certificate (file, reason).
    pub unreadable: Vec<(PathBuf, String)>,
}

/// What to trust.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Trust {
    /// A certificate file (DER or PEM) anywhere, or one in `<pki>/rejected` named by its
    /// file name or by the start of its thumbprint.
    File(String),
    /// Every certificate in `<pki>/rejected`.
    AllRejected,
}

/// `<pki>/rejected`, where refused client certificates land.
pub fn rejected_dir(pki_dir: &Path) -> PathBuf {
    CertificateStore::new(pki_dir).rejected_certs_dir()
}

/// `<pki>/trusted`, the trust list.
pub fn trusted_dir(pki_dir: &Path) -> PathBuf {
    CertificateStore::new(pki_dir).trusted_certs_dir()
}

fn read_cert(path: &Path) -> Result<(X509, CertInfo), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let cert = X509::from_der(&bytes)
        .or_else(|_| X509::from_pem(&bytes))
        .map_err(|_| {
            format!(
                "{}: not an X.509 certificate (DER or PEM); give the client's certificate, \
                 not its private key",
                path.display()
            )
        })?;
    let info = CertInfo {
        path: path.to_path_buf(),
        subject: cert.subject_name(),
        thumbprint: cert.thumbprint().as_hex_string(),
        not_after: cert.not_after().ok().map(|t| t.to_string()),
    };
    Ok((cert, info))
}

/// The certificate files of `dir`, sorted by name (none when it does not exist yet).
fn cert_files(dir: &Path) -> Result<Vec<PathBuf>, String> {
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(vec![]),
        Err(e) => return Err(format!("{}: {e}", dir.display())),
    };
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.is_file()
                && p.extension()
                    .is_some_and(|x| x.eq_ignore_ascii_case("der") || x.eq_ignore_ascii_case("pem"))
        })
        .collect();
    files.sort();
    Ok(files)
}

/// The rejected and trusted client certificates of `pki_dir`.
pub fn list(pki_dir: &Path) -> Result<Certificates, String> {
    let mut out = Certificates {
        rejected_dir: rejected_dir(pki_dir),
        trusted_dir: trusted_dir(pki_dir),
        ..Default::default()
    };
    for (dir, list) in [
        (out.rejected_dir.clone(), &mut out.rejected),
        (out.trusted_dir.clone(), &mut out.trusted),
    ] {
        for f in cert_files(&dir)? {
            match read_cert(&f) {
                Ok((_, info)) => list.push(info),
                Err(e) => out.unreadable.push((f, e)),
            }
        }
    }
    Ok(out)
}

/// Puts certificates into `<pki>/trusted` (under the name async-opcua looks for) and
/// takes them out of `<pki>/rejected` (a certificate there is refused whatever the trust
/// list says). Returns what was trusted, at its new place.
pub fn trust(pki_dir: &Path, what: &Trust) -> Result<Vec<CertInfo>, String> {
    let rejected = rejected_dir(pki_dir);
    let certs: Vec<(X509, CertInfo)> = match what {
        Trust::AllRejected => {
            let files = cert_files(&rejected)?;
            if files.is_empty() {
                return Err(format!(
                    "no rejected certificate in {}: a client's certificate lands there when \
                     it first tries the Basic256Sha256 endpoint (check --opcua-pki is the \
                     gateway's)",
                    rejected.display()
                ));
            }
            files
                .iter()
                .map(|f| read_cert(f))
                .collect::<Result<_, _>>()?
        }
        Trust::File(name) => vec![find(&rejected, name)?],
    };
    let trusted = trusted_dir(pki_dir);
    std::fs::create_dir_all(&trusted).map_err(|e| format!("{}: {e}", trusted.display()))?;
    let mut done = vec![];
    for (cert, mut info) in certs {
        let file_name = CertificateStore::cert_file_name(&cert);
        let der = cert
            .to_der()
            .map_err(|_| format!("{}: cannot encode the certificate", info.path.display()))?;
        let to = trusted.join(&file_name);
        std::fs::write(&to, der).map_err(|e| format!("{}: {e}", to.display()))?;
        // Out of the rejected folder: under async-opcua's name, and the file given.
        for old in [rejected.join(&file_name), info.path.clone()] {
            if old.parent() == Some(rejected.as_path()) && old.exists() {
                std::fs::remove_file(&old).map_err(|e| {
                    format!(
                        "{} trusted, but {} could not be removed ({e}): a certificate in the \
                         rejected folder is refused; remove it by hand",
                        to.display(),
                        old.display()
                    )
                })?;
            }
        }
        info.path = to;
        done.push(info);
    }
    Ok(done)
}

/// The certificate `name` names: a file, else a rejected one by file name or thumbprint.
fn find(rejected: &Path, name: &str) -> Result<(X509, CertInfo), String> {
    let path = Path::new(name);
    if path.is_file() {
        return read_cert(path);
    }
    let files = cert_files(rejected)?;
    if let Some(f) = files
        .iter()
        .find(|f| f.file_name().is_some_and(|n| n == name))
    {
        return read_cert(f);
    }
    let prefix = name.to_ascii_lowercase();
    let hex = prefix.len() >= 4 && prefix.bytes().all(|b| b.is_ascii_hexdigit());
    let mut matches = vec![];
    if hex {
        for f in &files {
            if let Ok((cert, info)) = read_cert(f) {
                if info.thumbprint.starts_with(&prefix) {
                    matches.push((cert, info));
                }
            }
        }
    }
    match matches.len() {
        1 => Ok(matches.remove(0)),
        0 => Err(format!(
            "{name}: no such certificate file, and no certificate in {} has this file name{} \
             (`hartkit opcua trust --list` shows them)",
            rejected.display(),
            if hex { " or thumbprint" } else { "" }
        )),
        _ => Err(format!(
            "{name}: {} rejected certificates have a thumbprint starting so ({}); give more \
             of it",
            matches.len(),
            matches
                .iter()
                .map(|(_, i)| i.thumbprint.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Test certificates made with openssl (`/CN=test client a`, ...; 100 years).
    fn cert(which: char) -> Vec<u8> {
        match which {
            'a' => include_bytes!("../testdata/client_a.der").to_vec(),
            'b' => include_bytes!("../testdata/client_b.der").to_vec(),
            _ => include_bytes!("../testdata/client_c.der").to_vec(),
        }
    }

    fn tmp(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("hart-opcua-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        d
    }

    #[test]
    fn trusts_rejected_by_thumbprint_and_all() {
        let pki = tmp("trust");
        let rejected = rejected_dir(&pki);
        std::fs::create_dir_all(&rejected).unwrap();
        let a = X509::from_der(&cert('a')).unwrap();
        let b = X509::from_der(&cert('b')).unwrap();
        for c in [&a, &b] {
            std::fs::write(
                rejected.join(CertificateStore::cert_file_name(c)),
                c.to_der().unwrap(),
            )
            .unwrap();
        }
        let l = list(&pki).unwrap();
        assert_eq!(l.rejected.len(), 2);
        assert!(l.trusted.is_empty());
        let ta = a.thumbprint().as_hex_string();
        let t = trust(&pki, &Trust::File(ta[..8].to_uppercase())).unwrap();
        assert_eq!(t.len(), 1);
        assert_eq!(t[0].thumbprint, ta);
        assert_eq!(
            t[0].path,
            trusted_dir(&pki).join(CertificateStore::cert_file_name(&a))
        );
        let l = list(&pki).unwrap();
        assert_eq!(l.rejected.len(), 1);
        assert_eq!(l.trusted.len(), 1);
        assert!(trust(&pki, &Trust::File("zz".into())).is_err());
        let t = trust(&pki, &Trust::AllRejected).unwrap();
        assert_eq!(t[0].thumbprint, b.thumbprint().as_hex_string());
        let l = list(&pki).unwrap();
        assert!(l.rejected.is_empty());
        assert_eq!(l.trusted.len(), 2);
        let e = trust(&pki, &Trust::AllRejected).unwrap_err();
        assert!(e.contains("no rejected certificate"), "{e}");
        let _ = std::fs::remove_dir_all(&pki);
    }

    #[test]
    fn trusts_a_file_given_and_refuses_a_key() {
        let pki = tmp("file");
        let outside = tmp("outside");
        std::fs::create_dir_all(&outside).unwrap();
        let f = outside.join("client.der");
        std::fs::write(&f, cert('c')).unwrap();
        let t = trust(&pki, &Trust::File(f.to_string_lossy().into())).unwrap();
        assert!(t[0].path.starts_with(trusted_dir(&pki)));
        assert!(
            f.exists(),
            "a file given from elsewhere is copied, not moved"
        );
        assert!(t[0].subject.contains("test client c"), "{:?}", t[0]);
        let junk = outside.join("client.pem");
        std::fs::write(&junk, b"-----BEGIN PRIVATE KEY-----\n").unwrap();
        let e = trust(&pki, &Trust::File(junk.to_string_lossy().into())).unwrap_err();
        assert!(e.contains("not an X.509 certificate"), "{e}");
        let _ = std::fs::remove_dir_all(&pki);
        let _ = std::fs::remove_dir_all(&outside);
    }
}
