//! What can be attempted, and where: courses (cohorts) with their memberships, and the stations
//! of the catalog (loaded by [`super::stations`]).

use axum::extract::State;
use axum::http::StatusCode;
use serde::{Deserialize, Serialize};
use time::OffsetDateTime;
use utoipa::ToSchema;
use uuid::Uuid;

use super::auth::{CurrentUser, Role};
use super::authz::course_visible;
use super::extract::{ApiJson, ApiPath};
use super::history::audit;
use super::state::RecordsState;
use crate::error::ApiError;

/// A role within a course.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum CourseRole {
    /// Does attempts in the course.
    Learner,
    /// Reviews the course's attempts.
    Faculty,
}

impl CourseRole {
    fn as_str(self) -> &'static str {
        match self {
            CourseRole::Learner => "learner",
            CourseRole::Faculty => "faculty",
        }
    }
}

/// A course.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct Course {
    /// Id.
    pub id: Uuid,
    /// Short code (unique).
    pub code: String,
    /// Title.
    pub title: String,
    /// The caller's role in it (none for admins who are not members).
    #[schema(value_type = Option<CourseRole>)]
    pub my_role: Option<String>,
    /// Created.
    #[serde(with = "time::serde::rfc3339")]
    #[schema(value_type = String, format = DateTime)]
    pub created_at: OffsetDateTime,
}

/// A member of a course.
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct Member {
    /// User id.
    pub user_id: Uuid,
    /// E-mail.
    pub email: String,
    /// Display name.
    pub display_name: String,
    /// Role in the course.
    #[schema(value_type = CourseRole)]
    pub role: String,
}

/// A course with its members (members are listed for faculty of the course and admins only).
#[derive(Debug, Serialize, Deserialize, ToSchema)]
pub struct CourseDetail {
    /// The course.
    pub course: Course,
    /// Members; empty for learners.
    pub members: Vec<Member>,
}

/// A new course.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct NewCourse {
    /// Short code, 1 to 64 characters (surrounding white space is trimmed), unique.
    #[schema(
        min_length = 1,
        max_length = 64,
        pattern = "^[^\\u0000]*[^\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000][^\\u0000]*$"
    )]
    pub code: String,
    /// Title, 1 to 200 characters (surrounding white space is trimmed).
    #[schema(
        min_length = 1,
        max_length = 200,
        pattern = "^[^\\u0000]*[^\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000][^\\u0000]*$"
    )]
    pub title: String,
}

/// Create a course (admin).
#[utoipa::path(post, path = "/api/courses", tag = "courses", request_body = NewCourse,
    responses((status = 201, body = Course), (status = 400), (status = 401), (status = 403), (status = 409)))]
pub async fn create_course(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiJson(req): ApiJson<NewCourse>,
) -> Result<(StatusCode, axum::Json<Course>), ApiError> {
    user.require(&[Role::Admin])?;
    let (code, title) = (req.code.trim().to_owned(), req.title.trim().to_owned());
    if code.is_empty()
        || code.chars().count() > 64
        || title.is_empty()
        || title.chars().count() > 200
    {
        return Err(ApiError::BadRequest(
            "code needs 1 to 64 characters and title 1 to 200".into(),
        ));
    }
    let id = Uuid::new_v4();
    let row: Option<(OffsetDateTime,)> =
        sqlx::query_as("INSERT INTO courses (id, code, title) VALUES ($1, $2, $3) ON CONFLICT (code) DO NOTHING RETURNING created_at")
            .bind(id)
            .bind(&code)
            .bind(&title)
            .fetch_optional(&state.pool)
            .await?;
    let (created_at,) =
        row.ok_or_else(|| ApiError::Conflict(format!("a course with code {code:?} exists")))?;
    audit(
        &state.pool,
        Some(user.id),
        "course_created",
        "course",
        &id.to_string(),
        serde_json::json!({ "code": code }),
    )
    .await?;
    Ok((
        StatusCode::CREATED,
        axum::Json(Course {
            id,
            code,
            title,
            my_role: None,
            created_at,
        }),
    ))
}

type CourseRow = (Uuid, String, String, Option<String>, OffsetDateTime);

fn course((id, code, title, my_role, created_at): CourseRow) -> Course {
    Course {
        id,
        code,
        title,
        my_role,
        created_at,
    }
}

/// Courses visible to the caller: all for admins, memberships for everyone else.
#[utoipa::path(get, path = "/api/courses", tag = "courses",
    responses((status = 200, body = Vec<Course>), (status = 401)))]
pub async fn list_courses(
    State(state): State<RecordsState>,
    user: CurrentUser,
) -> Result<axum::Json<Vec<Course>>, ApiError> {
    let rows: Vec<CourseRow> = sqlx::query_as(&format!(
        "SELECT c.id, c.code, c.title, (SELECT role FROM course_members m WHERE m.course_id = c.id AND m.user_id = $1), c.created_at
         FROM courses c WHERE {} ORDER BY c.code",
        course_visible(1, 2)
    ))
    .bind(user.id)
    .bind(user.is_admin())
    .fetch_all(&state.pool)
    .await?;
    Ok(axum::Json(rows.into_iter().map(course).collect()))
}

/// One course; members are listed for its faculty and admins.
#[utoipa::path(get, path = "/api/courses/{course_id}", tag = "courses",
    params(("course_id" = Uuid, Path, description = "Course id")),
    responses((status = 200, body = CourseDetail), (status = 400), (status = 401), (status = 404)))]
pub async fn get_course(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(course_id): ApiPath<Uuid>,
) -> Result<axum::Json<CourseDetail>, ApiError> {
    let row: Option<CourseRow> = sqlx::query_as(&format!(
        "SELECT c.id, c.code, c.title, (SELECT role FROM course_members m WHERE m.course_id = c.id AND m.user_id = $1), c.created_at
         FROM courses c WHERE c.id = $3 AND {}",
        course_visible(1, 2)
    ))
    .bind(user.id)
    .bind(user.is_admin())
    .bind(course_id)
    .fetch_optional(&state.pool)
    .await?;
    let course = course(row.ok_or_else(|| ApiError::NotFound("course".into()))?);
    let members = if user.is_admin() || course.my_role.as_deref() == Some("faculty") {
        sqlx::query_as::<_, (Uuid, String, String, String)>(
            "SELECT u.id, u.email, u.display_name, m.role FROM course_members m JOIN users u ON u.id = m.user_id
             WHERE m.course_id = $1 ORDER BY m.role, u.email",
        )
        .bind(course_id)
        .fetch_all(&state.pool)
        .await?
        .into_iter()
        .map(|(user_id, email, display_name, role)| Member { user_id, email, display_name, role })
        .collect()
    } else {
        Vec::new()
    };
    Ok(axum::Json(CourseDetail { course, members }))
}

/// A membership to set.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MembershipRequest {
    /// Role in the course. Learner memberships need a learner or faculty account; faculty
    /// memberships need a faculty or admin account.
    pub role: CourseRole,
}

/// Add a member to a course or change their role (admin).
#[utoipa::path(put, path = "/api/courses/{course_id}/members/{user_id}", tag = "courses", request_body = MembershipRequest,
    params(("course_id" = Uuid, Path, description = "Course id"), ("user_id" = Uuid, Path, description = "User id")),
    responses((status = 200, body = Member), (status = 400), (status = 401), (status = 403), (status = 404)))]
pub async fn put_member(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath((course_id, member_id)): ApiPath<(Uuid, Uuid)>,
    ApiJson(req): ApiJson<MembershipRequest>,
) -> Result<axum::Json<Member>, ApiError> {
    user.require(&[Role::Admin])?;
    let exists: bool = sqlx::query_scalar("SELECT EXISTS (SELECT 1 FROM courses WHERE id = $1)")
        .bind(course_id)
        .fetch_one(&state.pool)
        .await?;
    if !exists {
        return Err(ApiError::NotFound("course".into()));
    }
    let target: Option<(String, String, String)> =
        sqlx::query_as("SELECT email, display_name, role FROM users WHERE id = $1")
            .bind(member_id)
            .fetch_optional(&state.pool)
            .await?;
    let (email, display_name, account_role) =
        target.ok_or_else(|| ApiError::NotFound("user".into()))?;
    let allowed = match req.role {
        CourseRole::Learner => ["learner", "faculty"].contains(&account_role.as_str()),
        CourseRole::Faculty => ["faculty", "admin"].contains(&account_role.as_str()),
    };
    if !allowed {
        return Err(ApiError::BadRequest(format!(
            "a {account_role} account cannot be {} of a course",
            req.role.as_str()
        )));
    }
    let mut tx = state.pool.begin().await?;
    sqlx::query(
        "INSERT INTO course_members (course_id, user_id, role) VALUES ($1, $2, $3)
         ON CONFLICT (course_id, user_id) DO UPDATE SET role = EXCLUDED.role",
    )
    .bind(course_id)
    .bind(member_id)
    .bind(req.role.as_str())
    .execute(&mut *tx)
    .await?;
    audit(
        &mut *tx,
        Some(user.id),
        "course_member_set",
        "course",
        &course_id.to_string(),
        serde_json::json!({ "user_id": member_id, "role": req.role.as_str() }),
    )
    .await?;
    tx.commit().await?;
    Ok(axum::Json(Member {
        user_id: member_id,
        email,
        display_name,
        role: req.role.as_str().into(),
    }))
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
                    region: s.region_asset(),
                    modalities: s
                        .modalities
                        .iter()
                        .map(|m| m.as_str().to_string())
                        .collect(),
                    pass_threshold: s.rubric.pass_threshold,
                    criteria: s.rubric.criteria.len(),
                    critical_criteria: s.rubric.criteria.iter().filter(|c| c.critical).count(),
                    file_sha256: c.sha256.clone(),
                }
            })
            .collect(),
    )
}

/// Keys of a station target that learner accounts do not get: where it is (its position and
/// the landmark that places it). A learner gets each target's name and description, as a
/// physician knows what to aim for but not its coordinates.
const TARGET_KEYS_FOR_FACULTY: [&str; 2] = ["position_mm", "landmark"];

/// One station's definition (targets, instruments, rubric). Learner accounts get the targets
/// without their positions.
#[utoipa::path(get, path = "/api/stations/{station_id}", tag = "stations",
    params(("station_id" = String, Path, description = "Station id")),
    responses((status = 200, description = "The station definition (see assets/stations/README.md); for learner accounts its targets carry no position or landmark", body = Object), (status = 401), (status = 404)))]
pub async fn get_station(
    State(state): State<RecordsState>,
    user: CurrentUser,
    ApiPath(station_id): ApiPath<String>,
) -> Result<axum::Json<serde_json::Value>, ApiError> {
    let c = state
        .stations
        .get(&station_id)
        .ok_or_else(|| ApiError::NotFound(format!("station {station_id:?}")))?;
    let mut v = serde_json::to_value(&c.station).map_err(|e| ApiError::Internal(e.to_string()))?;
    v["file_sha256"] = c.sha256.clone().into();
    if user.role == Role::Learner
        && let Some(targets) = v.get_mut("targets").and_then(|t| t.as_array_mut())
    {
        for t in targets.iter_mut().filter_map(|t| t.as_object_mut()) {
            t.retain(|k, _| !TARGET_KEYS_FOR_FACULTY.contains(&k.as_str()));
        }
    }
    Ok(axum::Json(v))
}
