//! Object-level authorization as SQL predicates.
//!
//! Each predicate is spliced into the `WHERE` clause of the query that reads or changes the
//! object, with the caller's id and admin flag as bound parameters, so a row the caller may not
//! see is never fetched. The parameter numbers are arguments because queries bind other values
//! too.
//!
//! | who | sees an attempt | reviews an attempt |
//! |---|---|---|
//! | its learner | yes | never (nobody approves their own attempt) |
//! | faculty of its course | yes | yes |
//! | admin | yes | yes, unless it is their own |
//! | anyone else | no (404: existence is not revealed) | no |

/// `a` (an `attempts` row) is visible to user `$user` (admin flag `$admin`).
pub fn attempt_visible(user: u8, admin: u8) -> String {
    format!(
        "(a.learner_id = ${user} OR ${admin} OR EXISTS (SELECT 1 FROM course_members m \
         WHERE m.course_id = a.course_id AND m.user_id = ${user} AND m.role = 'faculty'))"
    )
}

/// `a` may be reviewed by `$user` (admin flag `$admin`), ignoring the own-attempt rule, which
/// queries check separately to give a clear 403.
pub fn attempt_reviewer(user: u8, admin: u8) -> String {
    format!(
        "(${admin} OR EXISTS (SELECT 1 FROM course_members m \
         WHERE m.course_id = a.course_id AND m.user_id = ${user} AND m.role = 'faculty'))"
    )
}

/// `c` (a `courses` row) is visible to `$user`: admins see all, others their memberships.
pub fn course_visible(user: u8, admin: u8) -> String {
    format!(
        "(${admin} OR EXISTS (SELECT 1 FROM course_members m WHERE m.course_id = c.id AND m.user_id = ${user}))"
    )
}
