//! Building blocks of the OpenAPI document for constraints utoipa's attributes cannot state
//! alone: patterns shared by many fields and JSON objects without NUL anywhere. The handlers
//! build their hand-written schemas (the activity kinds a client may send, the review queue's
//! states, the comment a returned attempt needs) from these and from the constants they check,
//! so the document cannot drift from the server.
//!
//! Strings in request bodies carry the pattern [`NO_NUL`] (or a stricter one) because
//! [`super::extract::ApiJson`] refuses a NUL in any string or key of a body (PostgreSQL stores
//! none); utoipa takes patterns only as literals, so the attributes repeat the text of these
//! constants and a unit test checks that they do. This module imports nothing of the records.

use utoipa::openapi::RefOr;
use utoipa::openapi::schema::{
    AdditionalProperties, ArrayBuilder, ArrayItems, ObjectBuilder, OneOfBuilder, Schema,
    SchemaType, Type,
};

/// A string without NUL (ECMA-262 and Python both read `\u0000`).
pub const NO_NUL: &str = "^[^\\u0000]*$";

/// A string without NUL that is not blank after trimming: one character that is neither NUL nor
/// Unicode `White_Space` (what Rust's `str::trim` removes, listed because regex dialects disagree
/// on `\s`).
pub const NOT_BLANK: &str = "^[^\\u0000]*[^\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000][^\\u0000]*$";

/// An e-mail address as accounts store it: one `@` with something on either side, and neither
/// NUL nor `White_Space` anywhere ([`super::users::normalize_email`]).
pub const EMAIL: &str = "^[^@\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000]+@[^@\\u0000\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000]+$";

/// A string schema with `pattern`.
pub fn text(pattern: &str) -> ObjectBuilder {
    ObjectBuilder::new()
        .schema_type(Type::String)
        .pattern(Some(pattern))
}

/// A string schema with one allowed value per item of `values`.
pub fn one_of_strings<'a>(values: impl IntoIterator<Item = &'a str>) -> ObjectBuilder {
    ObjectBuilder::new()
        .schema_type(Type::String)
        .enum_values(Some(values))
}

/// A JSON value whose strings and keys hold no NUL: scalars, and arrays and objects nested at
/// most `depth` levels.
fn value_without_nul(depth: usize) -> Schema {
    let mut one_of = OneOfBuilder::new()
        .item(text(NO_NUL))
        .item(ObjectBuilder::new().schema_type(Type::Number))
        .item(ObjectBuilder::new().schema_type(Type::Boolean))
        .item(ObjectBuilder::new().schema_type(Type::Null));
    if depth > 0 {
        one_of = one_of
            .item(
                ArrayBuilder::new().items(ArrayItems::RefOrSchema(Box::new(RefOr::T(
                    value_without_nul(depth - 1),
                )))),
            )
            .item(object_without_nul(depth - 1, false));
    }
    one_of.build().into()
}

/// A JSON object (or `null` when `nullable`) whose keys and nested strings hold no NUL, nested at
/// most `depth` levels below it.
pub fn object_without_nul(depth: usize, nullable: bool) -> ObjectBuilder {
    let ty = if nullable {
        SchemaType::from_iter([Type::Object, Type::Null])
    } else {
        SchemaType::Type(Type::Object)
    };
    ObjectBuilder::new()
        .schema_type(ty)
        .property_names(Some(text(NO_NUL)))
        .additional_properties(Some(AdditionalProperties::RefOr(RefOr::T(
            value_without_nul(depth),
        ))))
}

/// The body of every error response (`crate::error::ApiError`): a stable machine-readable code
/// and a message for people.
pub fn error_body() -> Schema {
    let detail = ObjectBuilder::new()
        .property(
            "code",
            ObjectBuilder::new()
                .schema_type(Type::String)
                .description(Some("Stable machine-readable code, e.g. `bad_request`")),
        )
        .property("message", ObjectBuilder::new().schema_type(Type::String))
        .required("code")
        .required("message");
    ObjectBuilder::new()
        .property("error", detail)
        .required("error")
        .description(Some(
            "An error: what went wrong, naming the field where one is at fault",
        ))
        .build()
        .into()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The literal patterns in `#[schema(pattern = ...)]` attributes equal these constants.
    #[test]
    fn attribute_patterns_repeat_the_constants() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("src/records");
        let mut seen = 0;
        for entry in std::fs::read_dir(dir).unwrap() {
            let text = std::fs::read_to_string(entry.unwrap().path()).unwrap();
            for (i, _) in text.match_indices("pattern = \"") {
                let rest = &text[i + "pattern = \"".len()..];
                let lit = &rest[..rest.find('"').unwrap()];
                let value = lit.replace("\\\\", "\\");
                if value.contains("u0000") {
                    assert!(
                        [NO_NUL, NOT_BLANK, EMAIL].contains(&value.as_str()),
                        "{value}"
                    );
                    seen += 1;
                }
            }
        }
        assert!(seen > 5, "only {seen} patterns found");
    }
}
