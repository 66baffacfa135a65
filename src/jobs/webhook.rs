//! Completion webhooks, signed the Standard Webhooks way: headers `webhook-id`,
//! `webhook-timestamp` and `webhook-signature: v1,<base64 HMAC-SHA256 of
//! "{id}.{timestamp}.{body}">`, the key being the base64 part of a `whsec_…` secret.
//! A delivery is retried with exponential backoff until the receiver answers 2xx or the
//! attempts run out; the id stays the same, so receivers can drop duplicates.

use super::metrics::JobMetrics;
use super::view::JobView;
use super::webhook_target::{refused_host, PublicOnly};
use base64::Engine as _;
use hmac::{Hmac, Mac};
use sha2::Sha256;
use std::time::Duration;

#[derive(Debug, thiserror::Error)]
pub enum WebhookError {
    #[error("the webhook secret must be `whsec_` followed by base64: {0}")]
    Secret(String),
    #[error("webhook_url must be an absolute http(s) URL: {0}")]
    Url(String),
    #[error("webhook_url must point at a public address: {0} (a server operator can allow private ones with --webhook-allow-private)")]
    NotPublic(String),
}

impl WebhookError {
    pub fn code(&self) -> &'static str {
        match self {
            WebhookError::Secret(_) => "webhook_secret_invalid",
            WebhookError::Url(_) | WebhookError::NotPublic(_) => "webhook_url_invalid",
        }
    }
}

#[derive(Clone)]
pub struct Webhooks {
    client: reqwest::Client,
    key: Option<Vec<u8>>,
    attempts: u32,
    first_delay: Duration,
    metrics: JobMetrics,
    allow_private: bool,
}

/// Checks a client-supplied `webhook_url` before a job is accepted (and again before it
/// is delivered): an absolute http(s) URL, and unless `allow_private`, not a literal
/// non-public address or a name for this machine ([`super::webhook_target`]).
pub fn check_url(url: &str, allow_private: bool) -> Result<(), WebhookError> {
    let u = match reqwest::Url::parse(url) {
        Ok(u) if matches!(u.scheme(), "http" | "https") && u.host().is_some() => u,
        _ => return Err(WebhookError::Url(url.chars().take(200).collect())),
    };
    match u.host().and_then(|h| refused_host(&h)) {
        Some(why) if !allow_private => Err(WebhookError::NotPublic(why)),
        _ => Ok(()),
    }
}

impl Webhooks {
    pub fn new(
        secret: Option<&str>,
        attempts: u32,
        first_delay: Duration,
        metrics: JobMetrics,
        allow_private: bool,
    ) -> Result<Webhooks, WebhookError> {
        let key = secret
            .map(|s| {
                let b64 = s.strip_prefix("whsec_").unwrap_or(s);
                base64::engine::general_purpose::STANDARD
                    .decode(b64)
                    .map_err(|e| WebhookError::Secret(e.to_string()))
            })
            .transpose()?;
        let mut client = reqwest::Client::builder()
            .timeout(Duration::from_secs(10))
            .redirect(reqwest::redirect::Policy::none());
        if !allow_private {
            client = client.dns_resolver(std::sync::Arc::new(PublicOnly));
        }
        let client = client
            .build()
            .map_err(|e| WebhookError::Secret(e.to_string()))?;
        Ok(Webhooks {
            client,
            key,
            attempts: attempts.max(1),
            first_delay,
            metrics,
            allow_private,
        })
    }

    /// The `webhook-signature` value for a message.
    pub fn sign(key: &[u8], id: &str, timestamp: i64, body: &str) -> String {
        let mut mac = Hmac::<Sha256>::new_from_slice(key).expect("HMAC takes any key length");
        mac.update(format!("{id}.{timestamp}.{body}").as_bytes());
        let sig = base64::engine::general_purpose::STANDARD.encode(mac.finalize().into_bytes());
        format!("v1,{sig}")
    }

    /// Delivers the job's end in the background.
    pub fn spawn_delivery(&self, url: String, job: JobView) {
        let this = self.clone();
        tokio::spawn(async move { this.deliver(&url, &job).await });
    }

    async fn deliver(&self, url: &str, job: &JobView) -> bool {
        let kind = format!("job.{}", job.status.as_str());
        let id = format!("{}.{}", job.id, job.status.as_str());
        // Checked at submission too; a job submitted to a replica with other settings, or
        // before this check existed, is not delivered to a private address either.
        if let Err(e) = check_url(url, self.allow_private) {
            tracing::warn!(job = %job.id, error = %e, "webhook not sent");
            self.metrics
                .webhook_deliveries
                .with_label_values(&["abandoned"])
                .inc();
            return false;
        }
        let mut delay = self.first_delay;
        for attempt in 1..=self.attempts {
            let timestamp = chrono::Utc::now().timestamp();
            let body = serde_json::json!({
                "type": kind,
                "timestamp": chrono::Utc::now().to_rfc3339(),
                "data": job,
            })
            .to_string();
            let mut req = self
                .client
                .post(url)
                .header("content-type", "application/json")
                .header("webhook-id", &id)
                .header("webhook-timestamp", timestamp.to_string());
            if let Some(key) = &self.key {
                req = req.header("webhook-signature", Self::sign(key, &id, timestamp, &body));
            }
            match req.body(body).send().await {
                Ok(r) if r.status().is_success() => {
                    self.metrics
                        .webhook_deliveries
                        .with_label_values(&["delivered"])
                        .inc();
                    return true;
                }
                Ok(r) => {
                    tracing::warn!(job = %job.id, attempt, status = %r.status(), "webhook refused")
                }
                Err(e) => tracing::warn!(job = %job.id, attempt, error = %e, "webhook failed"),
            }
            self.metrics
                .webhook_deliveries
                .with_label_values(&["retry"])
                .inc();
            if attempt < self.attempts {
                tokio::time::sleep(delay).await;
                delay = (delay * 4).min(Duration::from_secs(600));
            }
        }
        self.metrics
            .webhook_deliveries
            .with_label_values(&["abandoned"])
            .inc();
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn signature_matches_the_standard_webhooks_example() {
        // The example of the Standard Webhooks reference libraries.
        let key = base64::engine::general_purpose::STANDARD
            .decode("MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw")
            .unwrap();
        let sig = Webhooks::sign(
            &key,
            "msg_p5jXN8AQM9LWM0D4loKWxJek",
            1614265330,
            r#"{"test": 2432232314}"#,
        );
        assert_eq!(sig, "v1,g0hM9SsE+OTPJTGt/tmIKtSyZlE3uFJELVlNIOLJ1OE=");
    }

    #[test]
    fn urls_are_checked() {
        assert!(check_url("https://example.com/hook", false).is_ok());
        assert!(check_url("ftp://example.com", false).is_err());
        assert!(check_url("not a url", true).is_err());
        // Loopback only when the operator allows private addresses.
        let err = check_url("http://127.0.0.1:9/x", false).unwrap_err();
        assert_eq!(err.code(), "webhook_url_invalid");
        assert!(err.to_string().contains("public address"), "{err}");
        assert!(check_url("http://127.0.0.1:9/x", true).is_ok());
    }
}
