//! Which `Host` a page without a token answers to: the machine's own names. Without a token the
//! page listens on loopback only, so its browsers name it by a loopback address, `localhost`,
//! or a name a reverse proxy on the machine sends (`web.allowed_hosts`); any other name is a
//! site whose name was made to resolve to 127.0.0.1 (DNS rebinding), whose script would read
//! the build and acknowledge the alarm as the operator's page does.

use axum::http::{header, HeaderMap};

/// Whether the request's Host names the machine itself: a loopback IP address, `localhost`, or
/// one of `allowed` (any case), with or without a port of digits. No Host at all is an
/// HTTP/1.0 client (no browser is one; HTTP/2 is not served).
pub fn own_host(headers: &HeaderMap, allowed: &[String]) -> bool {
    let Some(host) = headers.get(header::HOST) else {
        return true;
    };
    host.to_str().ok().and_then(host_name).is_some_and(|name| {
        name.eq_ignore_ascii_case("localhost")
            || allowed.iter().any(|a| a.eq_ignore_ascii_case(name))
            || name
                .parse::<std::net::IpAddr>()
                .is_ok_and(|ip| ip.is_loopback())
    })
}

/// The name of a `Host` value without its port (`[::1]:8040` → `::1`); none when what follows
/// the name is not nothing or `:` and digits.
fn host_name(host: &str) -> Option<&str> {
    let (name, port) = match host.strip_prefix('[') {
        Some(v6) => match v6.split_once(']')? {
            (name, "") => (name, None),
            (name, rest) => (name, Some(rest.strip_prefix(':')?)),
        },
        None => match host.split_once(':') {
            Some((name, port)) => (name, Some(port)),
            None => (host, None),
        },
    };
    let port_ok = port.is_none_or(|p| !p.is_empty() && p.bytes().all(|b| b.is_ascii_digit()));
    (port_ok && !name.is_empty()).then_some(name)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with_host(host: &str) -> HeaderMap {
        let mut headers = HeaderMap::new();
        headers.insert(header::HOST, host.parse().unwrap());
        headers
    }

    #[test]
    fn only_the_machines_own_names_are_answered() {
        let allowed = ["Printer-PC.shop".to_string()];
        for own in [
            "127.0.0.1",
            "127.0.0.1:8040",
            "127.1.2.3:80",
            "[::1]",
            "[::1]:8040",
            "localhost",
            "LOCALHOST:8040",
            "printer-pc.shop:443",
        ] {
            assert!(own_host(&with_host(own), &allowed), "{own}");
        }
        for other in [
            "evil.example",
            "evil.example:80",
            "127.0.0.1:evil",
            "127.0.0.1:",
            "[::1]evil",
            "[::1]:80x",
            "[::ffff:10.0.0.1]:80",
            "10.0.0.5:8040",
            "localhost.",
            ":8040",
            "::1",
        ] {
            assert!(!own_host(&with_host(other), &allowed), "{other}");
        }
        assert!(own_host(&HeaderMap::new(), &[]), "no Host: HTTP/1.0");
    }
}
