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

/// The command line of a binary that writes one section: no arguments
/// (print only) or `--write FILE`; for anything else a usage line on
/// stderr and the exit status of a usage error.
pub fn write_target(binary: &str) -> Result<Option<String>, std::process::ExitCode> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match args.as_slice() {
        [] => Ok(None),
        [flag, path] if flag == "--write" => Ok(Some(path.clone())),
        _ => {
            eprintln!("usage: {binary} [--write FILE]");
            Err(std::process::ExitCode::from(2))
        }
    }
}

/// Prints `doc` and, with a `target` file, splices it into that file as
/// section `name` (the file is created when missing); the exit status.
pub fn publish(doc: &str, name: &str, target: Option<&str>) -> std::process::ExitCode {
    print!("{doc}");
    if let Some(path) = target {
        let old = std::fs::read_to_string(path).unwrap_or_default();
        if let Err(e) = std::fs::write(path, splice(&old, name, doc)) {
            eprintln!("writing {path}: {e}");
            return std::process::ExitCode::from(2);
        }
        eprintln!("wrote the section into {path}");
    }
    std::process::ExitCode::SUCCESS
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
