//! Uploads and results, in any `object_store` backend: a local directory by default, an
//! S3-compatible bucket in cluster mode. Keys are `jobs/<id>/<name>`, so deleting a job's
//! blobs is deleting one prefix.

use bytes::Bytes;
use futures_util::TryStreamExt;
use object_store::local::LocalFileSystem;
use object_store::path::Path as ObjectPath;
use object_store::{ObjectStore, PutPayload};
use std::path::Path;
use std::sync::Arc;

#[derive(Debug, thiserror::Error)]
pub enum BlobError {
    #[error("blob store unavailable: {0}")]
    Unavailable(String),
    #[error("blob store configuration: {0}")]
    Config(String),
}

impl BlobError {
    pub fn code(&self) -> &'static str {
        match self {
            BlobError::Unavailable(_) => "blob_store_unavailable",
            BlobError::Config(_) => "blob_store_config",
        }
    }
}

impl From<object_store::Error> for BlobError {
    fn from(e: object_store::Error) -> Self {
        BlobError::Unavailable(e.to_string())
    }
}

/// The names of a job's blobs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BlobKind {
    Input,
    ResultGlb,
    Skeleton,
}

impl BlobKind {
    fn name(self) -> &'static str {
        match self {
            BlobKind::Input => "input",
            BlobKind::ResultGlb => "result.glb",
            BlobKind::Skeleton => "skeleton.json",
        }
    }
}

#[derive(Clone)]
pub struct Blobs {
    store: Arc<dyn ObjectStore>,
    prefix: String,
}

impl Blobs {
    /// Blobs as files under `dir` (created if needed).
    pub fn local(dir: &Path) -> Result<Blobs, BlobError> {
        std::fs::create_dir_all(dir)
            .map_err(|e| BlobError::Config(format!("creating {}: {e}", dir.display())))?;
        let fs = LocalFileSystem::new_with_prefix(dir)
            .map_err(|e| BlobError::Config(format!("{}: {e}", dir.display())))?;
        Ok(Blobs::new(Arc::new(fs), ""))
    }

    /// Blobs at a URL: `s3://bucket/prefix` (endpoint, region and credentials from the
    /// usual AWS environment: `AWS_ENDPOINT_URL`, `AWS_REGION`, `AWS_ACCESS_KEY_ID`,
    /// `AWS_SECRET_ACCESS_KEY`; a plain `http://` endpoint is allowed) or `file:///dir`.
    pub fn from_url(url: &str) -> Result<Blobs, BlobError> {
        let u = url::Url::parse(url).map_err(|e| BlobError::Config(format!("{url}: {e}")))?;
        match u.scheme() {
            "s3" => {
                let bucket = u
                    .host_str()
                    .filter(|b| !b.is_empty())
                    .ok_or_else(|| BlobError::Config(format!("{url}: no bucket")))?;
                let mut b = object_store::aws::AmazonS3Builder::from_env().with_bucket_name(bucket);
                let endpoint = std::env::var("AWS_ENDPOINT_URL")
                    .or_else(|_| std::env::var("AWS_ENDPOINT"))
                    .ok();
                if let Some(ep) = endpoint {
                    b = b
                        .with_allow_http(ep.starts_with("http://"))
                        .with_endpoint(ep);
                }
                let store = b
                    .build()
                    .map_err(|e| BlobError::Config(format!("{url}: {e}")))?;
                Ok(Blobs::new(Arc::new(store), u.path()))
            }
            "file" => Blobs::local(Path::new(u.path())),
            other => Err(BlobError::Config(format!(
                "{url}: unsupported scheme {other}: (use s3:// or file://)"
            ))),
        }
    }

    /// Blobs in any store, under `prefix` (no leading or trailing `/` needed).
    pub fn new(store: Arc<dyn ObjectStore>, prefix: &str) -> Blobs {
        Blobs {
            store,
            prefix: prefix.trim_matches('/').to_string(),
        }
    }

    fn job_dir(&self, job: &str) -> ObjectPath {
        if self.prefix.is_empty() {
            ObjectPath::from(format!("jobs/{job}"))
        } else {
            ObjectPath::from(format!("{}/jobs/{job}", self.prefix))
        }
    }

    fn path(&self, job: &str, kind: BlobKind) -> ObjectPath {
        self.job_dir(job).child(kind.name())
    }

    pub async fn put(&self, job: &str, kind: BlobKind, bytes: Bytes) -> Result<(), BlobError> {
        self.store
            .put(&self.path(job, kind), PutPayload::from_bytes(bytes))
            .await?;
        Ok(())
    }

    /// `None` when the blob does not exist (never written, or deleted).
    pub async fn get(&self, job: &str, kind: BlobKind) -> Result<Option<Bytes>, BlobError> {
        match self.store.get(&self.path(job, kind)).await {
            Ok(r) => Ok(Some(r.bytes().await?)),
            Err(object_store::Error::NotFound { .. }) => Ok(None),
            Err(e) => Err(e.into()),
        }
    }

    /// Deletes every blob of `job`; deleting what is not there is not an error.
    pub async fn delete_job(&self, job: &str) -> Result<(), BlobError> {
        let dir = self.job_dir(job);
        let paths: Vec<ObjectPath> = self
            .store
            .list(Some(&dir))
            .map_ok(|m| m.location)
            .try_collect()
            .await?;
        for p in paths {
            match self.store.delete(&p).await {
                Ok(()) | Err(object_store::Error::NotFound { .. }) => {}
                Err(e) => return Err(e.into()),
            }
        }
        Ok(())
    }

    /// A cheap round trip (readiness): listing a prefix that is normally empty.
    pub async fn ping(&self) -> Result<(), BlobError> {
        let probe = if self.prefix.is_empty() {
            ObjectPath::from("readyz")
        } else {
            ObjectPath::from(format!("{}/readyz", self.prefix))
        };
        let _: Vec<_> = self.store.list(Some(&probe)).try_collect().await?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn put_get_delete() {
        let dir = tempfile::tempdir().unwrap();
        let b = Blobs::local(dir.path()).unwrap();
        b.put("j1", BlobKind::Input, Bytes::from_static(b"mesh"))
            .await
            .unwrap();
        b.put("j1", BlobKind::ResultGlb, Bytes::from_static(b"glb"))
            .await
            .unwrap();
        b.put("j2", BlobKind::Input, Bytes::from_static(b"other"))
            .await
            .unwrap();
        assert_eq!(
            b.get("j1", BlobKind::Input).await.unwrap().unwrap(),
            &b"mesh"[..]
        );
        b.delete_job("j1").await.unwrap();
        assert!(b.get("j1", BlobKind::Input).await.unwrap().is_none());
        assert!(b.get("j1", BlobKind::ResultGlb).await.unwrap().is_none());
        assert!(b.get("j2", BlobKind::Input).await.unwrap().is_some());
        b.delete_job("j1").await.unwrap();
        b.ping().await.unwrap();
    }
}
