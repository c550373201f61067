//! `docs/design.md` lists the path of a trace call, file by file and
//! function by function, for the default method and for one paper method
//! ("The path of a trace call"). This keeps the list true: every listed
//! function is still defined in its file, and the default method's path
//! stays within six files.

use std::path::Path;

/// The rows (`file`, functions) of the table under the heading that
/// starts with `heading`.
fn table(doc: &str, heading: &str) -> Vec<(String, Vec<String>)> {
    let start = doc
        .find(heading)
        .unwrap_or_else(|| panic!("docs/design.md has no heading {heading:?}"));
    let mut rows = Vec::new();
    let mut in_table = false;
    for line in doc[start..].lines().skip(1) {
        if line.starts_with('#') {
            break;
        }
        if !line.starts_with("| `") {
            if in_table {
                break;
            }
            continue;
        }
        in_table = true;
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        let file = cells[1].trim_matches('`').to_string();
        let fns = cells[2]
            .split(',')
            .map(|f| f.trim().trim_matches('`').to_string())
            .collect();
        rows.push((file, fns));
    }
    assert!(!rows.is_empty(), "no table under {heading:?}");
    rows
}

/// Every function of every row is defined (`fn name`) in the row's file.
fn check(rows: &[(String, Vec<String>)]) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    for (file, fns) in rows {
        let src = std::fs::read_to_string(root.join(file))
            .unwrap_or_else(|e| panic!("docs/design.md lists {file}, which cannot be read: {e}"));
        for f in fns {
            // `Type::name` names a method: look for `fn name`.
            let name = f.rsplit("::").next().unwrap();
            let defined =
                src.contains(&format!("fn {name}(")) || src.contains(&format!("fn {name}<"));
            assert!(
                defined,
                "docs/design.md lists `{f}` in {file}, which no longer defines `fn {name}`"
            );
        }
    }
}

#[test]
fn the_listed_trace_paths_exist() {
    let doc = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/design.md"))
        .expect("docs/design.md");
    let frustum = table(&doc, "### `bvh-frustum`");
    check(&frustum);
    let mut files: Vec<&str> = frustum.iter().map(|(f, _)| f.as_str()).collect();
    files.dedup();
    assert!(
        files.len() <= 6,
        "the default method's path takes {} files (at most 6): {files:?}",
        files.len()
    );
    check(&table(&doc, "### `bvh-ranged`"));
}
