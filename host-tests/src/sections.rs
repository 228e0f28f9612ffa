//! Named sections of a generated document: `<!-- NAME:start -->` ...
//! `<!-- NAME:end -->`. Several programs write `docs/results.md`: the one
//! that rewrites the whole page (`paper-tables`) keeps every section the
//! others wrote.

/// The opening and closing markers of section `name`.
pub fn markers(name: &str) -> (String, String) {
    (
        format!("<!-- {name}:start -->"),
        format!("<!-- {name}:end -->"),
    )
}

/// Section `name` of `doc` with its markers, if it has one.
pub fn extract<'a>(doc: &'a str, name: &str) -> Option<&'a str> {
    let (start, end) = markers(name);
    let a = doc.find(&start)?;
    let b = doc[a..].find(&end)? + a + end.len();
    Some(&doc[a..b])
}

/// `doc` with section `name` replaced by `body` between the markers, or,
/// without markers, with the section appended.
pub fn splice(doc: &str, name: &str, body: &str) -> String {
    let (start, end) = markers(name);
    let section = format!("{start}\n{}\n{end}", body.trim_end());
    match extract(doc, name) {
        Some(old) => doc.replacen(old, &section, 1),
        None => {
            let mut out = doc.trim_end().to_string();
            if !out.is_empty() {
                out.push_str("\n\n");
            }
            out.push_str(&section);
            out.push('\n');
            out
        }
    }
}

/// The names of the sections of `doc`, in order.
pub fn names(doc: &str) -> Vec<&str> {
    doc.match_indices("<!-- ")
        .filter_map(|(i, _)| {
            let rest = &doc[i + 5..];
            let name = rest.split(":start -->").next()?;
            (rest.starts_with(&format!("{name}:start -->"))
                && !name.is_empty()
                && !name.contains(char::is_whitespace))
            .then_some(name)
        })
        .collect()
}

/// `new` with every section of `old` spliced in (replacing `new`'s own,
/// or appended in `old`'s order).
pub fn keep_all(new: &str, old: &str) -> String {
    let mut out = new.to_string();
    for name in names(old) {
        if let Some(section) = extract(old, name) {
            let (start, end) = markers(name);
            let body = &section[start.len()..section.len() - end.len()];
            out = splice(&out, name, body.trim_start_matches('\n'));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sections_are_replaced_appended_and_kept() {
        let doc = "# A\n\ntext\n";
        let once = splice(doc, "one", "first");
        assert_eq!(
            once,
            "# A\n\ntext\n\n<!-- one:start -->\nfirst\n<!-- one:end -->\n"
        );
        let both = splice(&once, "two", "second\n");
        assert_eq!(names(&both), ["one", "two"]);
        let again = splice(&both, "one", "new");
        assert_eq!(
            extract(&again, "one"),
            Some("<!-- one:start -->\nnew\n<!-- one:end -->")
        );
        assert!(again.contains("second"));
        // A rewritten page keeps both sections, in order.
        let kept = keep_all("# B\n", &again);
        assert_eq!(
            kept,
            splice(&splice("# B\n", "one", "new"), "two", "second")
        );
        assert_eq!(keep_all("# B\n", doc), "# B\n");
    }
}
