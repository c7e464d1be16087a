//! Pushing a build's DICOM instances to archives (PACS): DICOMweb STOW-RS ([`stow`]) and DIMSE
//! C-STORE ([`cstore`]). Every instance the archive confirms or rejects is written to the push
//! log (`build_dir::pushlog`), so a push resumes where it stopped; [`live`] runs the push beside
//! the daemon, off the capture and processing paths.

mod connect;
pub mod cstore;
mod destination;
mod error;
mod instance;
pub mod live;
mod queue;
pub mod stow;

pub use destination::{Destination, Target};
pub use error::{PacsError, StoreError, TransportError, Unmentioned};
pub use instance::{status_text, Instance, Outcome, Sender, Unfinished, MAX_INSTANCE_BYTES};
pub use queue::{PushCount, Queue};

#[cfg(test)]
mod tests {
    use super::destination::base64;
    use super::*;
    use crate::config::pacs::PacsDestination;

    #[test]
    fn targets_from_urls_and_names() {
        let web = Destination::resolve("http://127.0.0.1:8042/dicom-web/", &[]).unwrap();
        assert_eq!(web.name, "127.0.0.1_8042_dicom-web");
        assert!(
            matches!(web.target, Target::Stow { ref url, .. } if url == "http://127.0.0.1:8042/dicom-web")
        );
        let dimse = Destination::resolve("dicom://ORTHANC@localhost:4242", &[]).unwrap();
        assert_eq!(
            dimse.target,
            Target::CStore {
                host: "localhost".into(),
                port: 4242,
                called_ae: "ORTHANC".into(),
                calling_ae: "LAYERWISE".into()
            }
        );
        for bad in ["orthanc", "dicom://host:4242", "dicom://AE@host", "ftp://x"] {
            assert!(Destination::resolve(bad, &[]).is_err(), "{bad}");
        }
    }

    #[test]
    fn basic_auth_is_base64_of_user_and_secret_file() {
        assert_eq!(
            base64(b"Aladdin:open sesame"),
            "QWxhZGRpbjpvcGVuIHNlc2FtZQ=="
        );
        assert_eq!(base64(b"ab"), "YWI=");
        let dir = tempfile::tempdir().unwrap();
        let secret = dir.path().join("secret");
        std::fs::write(&secret, "open sesame\n").unwrap();
        let config: PacsDestination = toml::from_str(&format!(
            "name = \"a\"\nurl = \"https://pacs/dicom-web\"\nauth = \"basic\"\nuser = \"Aladdin\"\nsecret_file = {:?}\n",
            secret
        ))
        .unwrap();
        let destination = Destination::from_config(&config).unwrap();
        assert!(matches!(destination.target,
            Target::Stow { authorization: Some(ref a), .. } if a == "Basic QWxhZGRpbjpvcGVuIHNlc2FtZQ=="));
        let missing = PacsDestination {
            secret_file: Some(dir.path().join("none")),
            ..config
        };
        let err = Destination::from_config(&missing).unwrap_err().to_string();
        assert!(err.contains("secret_file") && err.contains("none"), "{err}");
    }
}
