//! The shipped unit passes `systemd-analyze verify` (with ExecStart pointing at this build).

use crate::common::assert_success;

/// The unit as shipped.
fn shipped_unit() -> String {
    std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/systemd/layerwise.service"
    ))
    .unwrap()
}

/// The unit with ExecStart pointing at this build, written into `dir`.
fn unit_for_this_build(unit: &str, dir: &std::path::Path) -> std::path::PathBuf {
    let path = dir.join("layerwise.service");
    std::fs::write(
        &path,
        unit.replace("/usr/local/bin/layerwise", env!("CARGO_BIN_EXE_layerwise")),
    )
    .unwrap();
    path
}

#[test]
fn unit_passes_systemd_analyze_verify() {
    let unit = shipped_unit();
    for required in [
        "Type=notify",
        "WatchdogSec=",
        "Restart=on-failure",
        "User=layerwise",
        "NoNewPrivileges=yes",
        "ProtectSystem=strict",
    ] {
        assert!(unit.contains(required), "the unit lacks {required}");
    }
    let dir = tempfile::tempdir().unwrap();
    let path = unit_for_this_build(&unit, dir.path());
    let out = std::process::Command::new("systemd-analyze")
        .arg("verify")
        .arg(&path)
        .output()
        .expect("systemd-analyze is needed: the README's test command installs systemd");
    assert_success(&out);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !stderr.contains("layerwise.service"),
        "warnings about the unit: {stderr}"
    );
}

#[test]
fn unit_exposure_is_at_most_1_5_in_systemd_analyze_security() {
    let unit = shipped_unit();
    let dir = tempfile::tempdir().unwrap();
    let path = unit_for_this_build(&unit, dir.path());
    let out = std::process::Command::new("systemd-analyze")
        .args(["security", "--offline=true", "--no-pager"])
        .arg(&path)
        .output()
        .expect("systemd-analyze is needed: the README's test command installs systemd");
    let text = String::from_utf8_lossy(&out.stdout);
    let score: f64 = text
        .lines()
        .find_map(|l| l.split("Overall exposure level for").nth(1))
        .and_then(|rest| rest.split(':').nth(1))
        .and_then(|s| s.split_whitespace().next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no exposure level in: {text}"));
    assert!(score <= 1.5, "exposure {score} > 1.5:\n{text}");
}

/// IP is allowed for the operator page on loopback only: any other address is a drop-in the
/// operator adds on purpose (docs/configuration.md, "The operator page: network, limits and API").
#[test]
fn unit_allows_ip_on_loopback_only() {
    let unit = shipped_unit();
    let values = |key: &str| -> Vec<String> {
        unit.lines()
            .filter_map(|l| l.strip_prefix(&format!("{key}=")))
            .map(str::to_string)
            .collect()
    };
    assert_eq!(values("IPAddressDeny"), ["any"]);
    assert_eq!(values("IPAddressAllow"), ["localhost"]);
    let families = values("RestrictAddressFamilies").join(" ");
    for family in ["AF_UNIX", "AF_NETLINK", "AF_INET", "AF_INET6"] {
        assert!(families.split(' ').any(|f| f == family), "{families}");
    }
    assert!(!families.contains("AF_PACKET"), "{families}");
}
