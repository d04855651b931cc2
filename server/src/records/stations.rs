//! The station catalog: `assets/stations/*.toml`, validated by `sim_core::rubric`, registered in
//! `station_revisions` with each file's SHA-256. Its HTTP handlers are in [`super::catalogue`].

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use sim_core::rubric::{Station, load_station_dir};
use sqlx::PgPool;

/// A loaded station and the SHA-256 of its file.
#[derive(Debug, Clone)]
pub struct CatalogStation {
    /// The validated definition.
    pub station: Station,
    /// SHA-256 (hex) of the file's bytes.
    pub sha256: String,
}

impl CatalogStation {
    /// Records this revision in `station_revisions` (idempotent); fails if the recorded file hash
    /// of the same revision differs.
    pub async fn register<'e>(&self, exec: impl sqlx::PgExecutor<'e>) -> anyhow::Result<()> {
        let (id, rev, rubric_rev) = (
            &self.station.id,
            self.station.revision as i32,
            self.station.rubric.revision as i32,
        );
        let stored: String = sqlx::query_scalar(
            "WITH ins AS (
                 INSERT INTO station_revisions (station_id, revision, rubric_revision, file_sha256, definition)
                 VALUES ($1, $2, $3, $4, $5) ON CONFLICT DO NOTHING RETURNING file_sha256)
             SELECT file_sha256 FROM ins
             UNION ALL
             SELECT file_sha256 FROM station_revisions WHERE station_id = $1 AND revision = $2 AND rubric_revision = $3
             LIMIT 1",
        )
        .bind(id)
        .bind(rev)
        .bind(rubric_rev)
        .bind(&self.sha256)
        .bind(serde_json::to_value(&self.station)?)
        .fetch_one(exec)
        .await?;
        anyhow::ensure!(
            stored == self.sha256,
            "station {id} revision {rev} / rubric revision {rubric_rev} changed since it was first \
             used (file hash {} now, {stored} recorded): bump `revision` or `rubric.revision`",
            self.sha256
        );
        Ok(())
    }
}

/// Stations by id (current revisions).
#[derive(Debug, Clone, Default)]
pub struct StationCatalog {
    /// Stations by id.
    pub stations: BTreeMap<String, CatalogStation>,
}

impl StationCatalog {
    /// Loads and validates every station in `dir`.
    pub fn load(dir: &Path) -> anyhow::Result<StationCatalog> {
        let files = load_station_dir(dir)
            .with_context(|| format!("loading stations from {}", dir.display()))?;
        let stations = files
            .into_iter()
            .map(|f| {
                let sha256 = sim_core::hash::sha256_hex(f.text.as_bytes());
                (
                    f.station.id.clone(),
                    CatalogStation {
                        station: f.station,
                        sha256,
                    },
                )
            })
            .collect();
        Ok(StationCatalog { stations })
    }

    /// Records every revision in the database; fails if a revision already recorded has a
    /// different file hash (a published revision was edited in place instead of bumped).
    pub async fn register(&self, pool: &PgPool) -> anyhow::Result<()> {
        for s in self.stations.values() {
            s.register(pool).await?;
        }
        Ok(())
    }

    /// The current revision of a station.
    pub fn get(&self, id: &str) -> Option<&CatalogStation> {
        self.stations.get(id)
    }
}
