//! The station catalog: `assets/stations/*.toml`, validated by `sim_core::rubric`, registered in
//! `station_revisions` with each file's SHA-256.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::Context;
use axum::extract::State;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use sim_core::rubric::{Modality, Station, load_station_dir};
use sqlx::PgPool;
use utoipa::ToSchema;

use super::RecordsState;
use super::auth::CurrentUser;
use super::extract::ApiPath;
use crate::ApiError;

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
                let sha256 = hex::encode(Sha256::digest(f.text.as_bytes()));
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

/// A station in the catalog listing.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct StationSummary {
    /// Station id.
    pub id: String,
    /// Station revision.
    pub revision: u32,
    /// Rubric revision.
    pub rubric_revision: u32,
    /// Title.
    pub title: String,
    /// Anatomy region.
    pub region: String,
    /// Modalities (`fluoroscopy`, `ultrasound`).
    pub modalities: Vec<String>,
    /// Pass threshold of the weighted score.
    pub pass_threshold: f64,
    /// Number of criteria.
    pub criteria: usize,
    /// Number of critical criteria.
    pub critical_criteria: usize,
    /// SHA-256 of the station file.
    pub file_sha256: String,
}

fn modality_name(m: Modality) -> String {
    match m {
        Modality::Fluoroscopy => "fluoroscopy".into(),
        Modality::Ultrasound => "ultrasound".into(),
    }
}

/// Every station (current revisions).
#[utoipa::path(get, path = "/api/stations", tag = "stations",
    responses((status = 200, body = Vec<StationSummary>), (status = 401)))]
pub async fn list_stations(
    State(state): State<RecordsState>,
    _user: CurrentUser,
) -> axum::Json<Vec<StationSummary>> {
    axum::Json(
        state
            .stations
            .stations
            .values()
            .map(|c| {
                let s = &c.station;
                StationSummary {
                    id: s.id.clone(),
                    revision: s.revision,
                    rubric_revision: s.rubric.revision,
                    title: s.title.clone(),
                    region: s.region.clone(),
                    modalities: s.modalities.iter().map(|m| modality_name(*m)).collect(),
                    pass_threshold: s.rubric.pass_threshold,
                    criteria: s.rubric.criteria.len(),
                    critical_criteria: s.rubric.criteria.iter().filter(|c| c.critical).count(),
                    file_sha256: c.sha256.clone(),
                }
            })
            .collect(),
    )
}

/// One station's full definition (targets, instruments, rubric).
#[utoipa::path(get, path = "/api/stations/{station_id}", tag = "stations",
    params(("station_id" = String, Path, description = "Station id")),
    responses((status = 200, description = "The station definition (see assets/stations/README.md)", body = Object), (status = 401), (status = 404)))]
pub async fn get_station(
    State(state): State<RecordsState>,
    _user: CurrentUser,
    ApiPath(station_id): ApiPath<String>,
) -> Result<axum::Json<serde_json::Value>, ApiError> {
    let c = state
        .stations
        .get(&station_id)
        .ok_or_else(|| ApiError::NotFound(format!("station {station_id:?}")))?;
    let mut v = serde_json::to_value(&c.station).map_err(|e| ApiError::Internal(e.to_string()))?;
    v["file_sha256"] = c.sha256.clone().into();
    Ok(axum::Json(v))
}
