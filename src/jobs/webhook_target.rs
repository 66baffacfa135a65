//! Where a webhook may be sent. `webhook_url` comes from the client, and the server POSTs
//! to it from inside the operator's network: without a check, any client could make the
//! service call its own loopback, the cluster's private addresses or a cloud metadata
//! endpoint (169.254.169.254). By default only addresses the public internet routes are
//! allowed; an operator testing against a local receiver opts in
//! (`--webhook-allow-private`).
//!
//! Literal IPs are refused when the job is submitted; host names are resolved at
//! delivery by [`PublicOnly`], which drops non-public answers, and the connection goes to
//! an address it returned, so a name that re-resolves to a private address between the
//! check and the connection (DNS rebinding) still cannot reach one.

use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr};

/// Whether the public internet routes `ip`: not loopback, private, shared (CGNAT),
/// link-local, unspecified, broadcast, multicast, documentation, benchmarking or reserved
/// space; IPv4-mapped and NAT64 IPv6 addresses are judged by the IPv4 address they carry.
pub fn is_public(ip: IpAddr) -> bool {
    match ip {
        IpAddr::V4(v4) => public_v4(v4),
        IpAddr::V6(v6) => public_v6(v6),
    }
}

fn public_v4(ip: Ipv4Addr) -> bool {
    let [a, b, c, _] = ip.octets();
    let special = ip.is_loopback()
        || ip.is_private()
        || ip.is_link_local()
        || ip.is_unspecified()
        || ip.is_broadcast()
        || ip.is_multicast()
        || a == 0
        || (a == 100 && (64..128).contains(&b))
        || (a == 192 && b == 0 && (c == 0 || c == 2))
        || (a == 198 && (b == 18 || b == 19))
        || (a == 198 && b == 51 && c == 100)
        || (a == 203 && b == 0 && c == 113)
        || a >= 240;
    !special
}

fn public_v6(ip: Ipv6Addr) -> bool {
    if let Some(v4) = ip.to_ipv4_mapped() {
        return public_v4(v4);
    }
    let s = ip.segments();
    if s[0] == 0x64 && s[1] == 0xff9b && s[2..6] == [0; 4] {
        return public_v4(Ipv4Addr::new(
            (s[6] >> 8) as u8,
            s[6] as u8,
            (s[7] >> 8) as u8,
            s[7] as u8,
        ));
    }
    let special = ip.is_loopback()
        || ip.is_unspecified()
        || ip.is_multicast()
        || (s[0] & 0xfe00) == 0xfc00
        || (s[0] & 0xffc0) == 0xfe80
        || (s[0] == 0x2001 && s[1] == 0x0db8)
        // IPv4-compatible (deprecated) addresses, ::a.b.c.d.
        || s[..6] == [0; 6];
    !special
}

/// Why a URL's host is not allowed, if it is not: a literal non-public address, or a name
/// that always means this machine.
pub fn refused_host(host: &url::Host<&str>) -> Option<String> {
    match host {
        url::Host::Ipv4(ip) if !public_v4(*ip) => Some(format!("{ip} is not a public address")),
        url::Host::Ipv6(ip) if !public_v6(*ip) => Some(format!("{ip} is not a public address")),
        url::Host::Domain(d) => {
            let d = d.trim_end_matches('.').to_ascii_lowercase();
            (d == "localhost" || d.ends_with(".localhost")).then(|| format!("{d} is this machine"))
        }
        _ => None,
    }
}

/// A resolver that answers only with public addresses, and fails for a name that has none.
pub struct PublicOnly;

impl reqwest::dns::Resolve for PublicOnly {
    fn resolve(&self, name: reqwest::dns::Name) -> reqwest::dns::Resolving {
        let host = name.as_str().to_string();
        Box::pin(async move {
            // Port 0: the connector puts the URL's port on every address returned.
            let all: Vec<SocketAddr> = tokio::net::lookup_host((host.as_str(), 0)).await?.collect();
            let public: Vec<SocketAddr> = all.into_iter().filter(|a| is_public(a.ip())).collect();
            if public.is_empty() {
                return Err(format!(
                    "{host} has no public address (webhooks go only to public addresses)"
                )
                .into());
            }
            Ok(Box::new(public.into_iter()) as reqwest::dns::Addrs)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn public(s: &str) -> bool {
        is_public(s.parse().unwrap())
    }

    #[test]
    fn private_and_special_addresses_are_not_public() {
        for ip in [
            "127.0.0.1",
            "10.1.2.3",
            "172.16.0.1",
            "192.168.1.1",
            "169.254.169.254",
            "100.64.0.1",
            "0.0.0.0",
            "0.1.2.3",
            "255.255.255.255",
            "224.0.0.1",
            "192.0.2.1",
            "198.18.0.1",
            "240.0.0.1",
            "::1",
            "::",
            "fd00::1",
            "fe80::1",
            "ff02::1",
            "2001:db8::1",
            "::ffff:127.0.0.1",
            "::ffff:10.0.0.1",
            "64:ff9b::a9fe:a9fe",
            "::7f00:1",
        ] {
            assert!(!public(ip), "{ip}");
        }
        for ip in [
            "1.1.1.1",
            "8.8.8.8",
            "100.128.0.1",
            "172.32.0.1",
            "2606:4700:4700::1111",
            "::ffff:1.1.1.1",
            "64:ff9b::808:808",
        ] {
            assert!(public(ip), "{ip}");
        }
    }

    #[test]
    fn hosts_are_refused_by_literal_or_by_name() {
        let host = |u: &str| {
            let u = url::Url::parse(u).unwrap();
            refused_host(&u.host().unwrap())
        };
        assert!(host("http://127.0.0.1:9/x").is_some());
        assert!(host("http://[::1]/x").is_some());
        assert!(host("http://169.254.169.254/latest").is_some());
        // A decimal-encoded 127.0.0.1 is parsed as the address it is.
        assert!(host("http://2130706433/").is_some());
        assert!(host("http://LocalHost./x").is_some());
        assert!(host("http://api.localhost/x").is_some());
        assert!(host("https://example.com/hook").is_none());
        assert!(host("https://8.8.8.8/hook").is_none());
    }

    #[tokio::test]
    async fn the_resolver_drops_private_answers() {
        use reqwest::dns::Resolve;
        use std::str::FromStr;
        // `localhost` resolves (from /etc/hosts) to loopback only.
        let name = reqwest::dns::Name::from_str("localhost").unwrap();
        let err = match PublicOnly.resolve(name).await {
            Ok(addrs) => panic!("resolved to {:?}", addrs.collect::<Vec<_>>()),
            Err(e) => e.to_string(),
        };
        assert!(
            err.contains("no public address") || err.contains("failed to lookup"),
            "{err}"
        );
    }
}
