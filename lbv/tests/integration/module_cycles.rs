//! No module of a firmware core imports one that imports it back, directly or round a longer circle: each core's
//! modules form layers a reader can take one at a time (docs/design.md, "Layout").
//!
//! The graph is read from the sources as text: the modules are the files the library's `mod` declarations reach
//! (test modules left out), and a module depends on another when its code (comments left out) names a path
//! `crate::a::b::...` or `super::...` that resolves to it, the longest prefix that is a module. A use of an item
//! of the crate's root (`lib.rs`) is not an edge: the root is the crate's face, and declares every module.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A module's path from the crate root, `["update", "own"]` for `crate::update::own`.
type Module = Vec<String>;

/// The crates whose modules are checked.
const CRATES: [&str; 2] = ["thruster-fw", "lbv-master-fw"];

#[test]
fn no_firmware_module_imports_one_that_imports_it_back() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    for name in CRATES {
        let modules = modules(&root.join(name).join("src"));
        assert!(modules.len() > 10, "{name}: {} modules read", modules.len());
        let graph = dependencies(&modules);
        let cycles = cycles(&graph);
        assert!(
            cycles.is_empty(),
            "{name}: modules that import each other round a circle: {}",
            cycles
                .iter()
                .map(|cycle| cycle.iter().map(|m| m.join("::")).collect::<Vec<_>>().join(" -> "))
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
}

#[test]
fn a_circle_is_found() {
    let text = |s: &str| s.to_string();
    let modules = BTreeMap::from([
        (vec![text("a")], without_tests("use crate::b::X;")),
        (
            vec![text("b")],
            without_tests("// crate::a is only named here\nfn f() { super::c::g() }"),
        ),
        (vec![text("c")], without_tests("use crate::{a::Y, d};")),
        (
            vec![text("d")],
            without_tests("#[cfg(test)]\nmod tests {\n    use crate::c::Z;\n}"),
        ),
    ]);
    let graph = dependencies(&modules);
    assert_eq!(
        graph[&vec![text("c")]],
        BTreeSet::from([vec![text("a")], vec![text("d")]])
    );
    assert_eq!(cycles(&graph).len(), 1, "{graph:?}");
}

/// Every module the library's `mod` declarations reach, with its code, from `src/lib.rs`.
fn modules(src: &Path) -> BTreeMap<Module, String> {
    let mut found = BTreeMap::new();
    let mut pending = vec![(Module::new(), src.join("lib.rs"))];
    while let Some((module, file)) = pending.pop() {
        let text = std::fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let code = without_tests(&text);
        // The folder a module's children live in: beside lib.rs for the root, `a/` for `a.rs`.
        let children_dir: PathBuf = if module.is_empty() {
            src.to_path_buf()
        } else {
            src.join(module.join("/"))
        };
        for child in declared(&code) {
            let mut path = module.clone();
            path.push(child.clone());
            let file = [
                children_dir.join(format!("{child}.rs")),
                children_dir.join(&child).join("mod.rs"),
            ]
            .into_iter()
            .find(|file| file.exists());
            if let Some(file) = file {
                pending.push((path, file));
            }
        }
        found.insert(module, code);
    }
    found
}

/// The code of a file without its comments and without what follows its test module's attribute (the tests sit
/// at the end of a file, by this project's habit).
fn without_tests(text: &str) -> String {
    let mut code = String::new();
    let mut lines = text.lines().peekable();
    while let Some(line) = lines.next() {
        let trimmed = line.trim_start();
        if trimmed.starts_with("#[cfg(test)]") {
            // The test module itself, or a test-only item: skip the item that follows.
            if lines
                .peek()
                .is_some_and(|next| next.trim_start().starts_with("mod tests"))
            {
                if lines.peek().is_some_and(|next| next.trim_end().ends_with('{')) {
                    break;
                }
                lines.next();
            }
            continue;
        }
        if trimmed.starts_with("//") {
            continue;
        }
        code.push_str(line.split("//").next().unwrap_or_default());
        code.push('\n');
    }
    code
}

/// The modules `code` declares (`mod x;`, `pub mod x;`, `pub(crate) mod x;`), test-only ones left out.
fn declared(code: &str) -> Vec<String> {
    let mut children = Vec::new();
    let mut test_only = false;
    for line in code.lines().map(str::trim) {
        if line.starts_with("#[cfg(") && line.contains("test") {
            test_only = true;
            continue;
        }
        let rest = line
            .strip_prefix("pub(crate) mod ")
            .or_else(|| line.strip_prefix("pub mod "))
            .or_else(|| line.strip_prefix("mod "));
        if let Some(name) = rest.and_then(|rest| rest.strip_suffix(';'))
            && !std::mem::take(&mut test_only)
        {
            children.push(name.to_string());
        }
        if !line.starts_with("#[") {
            test_only = false;
        }
    }
    children
}

/// Each module's dependencies on the others (not on itself, its ancestors' root, or the crate root).
fn dependencies(modules: &BTreeMap<Module, String>) -> BTreeMap<Module, BTreeSet<Module>> {
    modules
        .iter()
        .map(|(module, code)| {
            let mut deps = BTreeSet::new();
            for path in paths(code) {
                let absolute: Module = match path.first().map(String::as_str) {
                    Some("crate") => path[1..].to_vec(),
                    Some("super") => {
                        let ups = path.iter().take_while(|s| *s == "super").count();
                        let mut base = module.clone();
                        base.truncate(module.len().saturating_sub(ups));
                        base.extend(path[ups..].iter().cloned());
                        base
                    }
                    _ => continue,
                };
                let target = (1..=absolute.len())
                    .rev()
                    .map(|n| absolute[..n].to_vec())
                    .find(|prefix| modules.contains_key(prefix));
                if let Some(target) = target
                    && target != *module
                {
                    deps.insert(target);
                }
            }
            (module.clone(), deps)
        })
        .collect()
}

/// Every path that starts with `crate::` or `super::` in `code`, a `use` group's branches each as a path of its own.
fn paths(code: &str) -> Vec<Vec<String>> {
    let mut found = Vec::new();
    let bytes: Vec<char> = code.chars().collect();
    let mut i = 0;
    while i < bytes.len() {
        let word_start = i == 0 || !(bytes[i - 1].is_alphanumeric() || bytes[i - 1] == '_' || bytes[i - 1] == ':');
        let rest: String = bytes[i..bytes.len().min(i + 7)].iter().collect();
        if word_start && (rest.starts_with("crate::") || rest.starts_with("super::")) {
            let (paths, end) = path_at(&bytes, i);
            found.extend(paths);
            i = end;
        } else {
            i += 1;
        }
    }
    found
}

/// The path (or, with a `{...}` group, the paths) starting at `start`, and where it ends.
fn path_at(chars: &[char], start: usize) -> (Vec<Vec<String>>, usize) {
    let mut segments = Vec::new();
    let mut i = start;
    loop {
        let begin = i;
        while i < chars.len() && (chars[i].is_alphanumeric() || chars[i] == '_') {
            i += 1;
        }
        if i > begin {
            segments.push(chars[begin..i].iter().collect::<String>());
        }
        if chars.get(i) == Some(&':') && chars.get(i + 1) == Some(&':') {
            i += 2;
            if chars.get(i) == Some(&'{') {
                // A group: each branch is a path after the prefix.
                let mut paths = Vec::new();
                let mut depth = 0;
                let mut branch_start = i + 1;
                let mut j = i;
                while j < chars.len() {
                    match chars[j] {
                        '{' => depth += 1,
                        '}' => {
                            depth -= 1;
                            if depth == 0 {
                                break;
                            }
                        }
                        ',' if depth == 1 => {
                            paths.extend(branch(chars, branch_start, j, &segments));
                            branch_start = j + 1;
                        }
                        _ => {}
                    }
                    j += 1;
                }
                paths.extend(branch(chars, branch_start, j, &segments));
                return (paths, j + 1);
            }
            continue;
        }
        return (vec![segments], i.max(start + 1));
    }
}

/// One branch of a `use` group, `chars[from..to]`, after `prefix`.
fn branch(chars: &[char], from: usize, to: usize, prefix: &[String]) -> Vec<Vec<String>> {
    let text: String = chars[from..to].iter().collect();
    let text = text.trim();
    if text.is_empty() || text == "self" {
        return vec![prefix.to_vec()];
    }
    let inner: Vec<char> = text.chars().collect();
    let (paths, _) = path_at(&inner, 0);
    paths
        .into_iter()
        .map(|path| {
            prefix
                .iter()
                .cloned()
                .chain(path.into_iter().filter(|s| s != "self"))
                .collect()
        })
        .collect()
}

/// The circles of `graph`: for each strongly connected set of more than one module, one of its members' circle.
fn cycles(graph: &BTreeMap<Module, BTreeSet<Module>>) -> Vec<Vec<Module>> {
    let mut circles = Vec::new();
    let mut reported = BTreeSet::new();
    for start in graph.keys() {
        if reported.contains(start) {
            continue;
        }
        // A breadth-first walk from `start`'s dependencies back to `start` gives the shortest circle through it.
        let mut came_from: BTreeMap<Module, Module> = BTreeMap::new();
        let mut frontier: Vec<Module> = vec![start.clone()];
        let mut found = None;
        'walk: while !frontier.is_empty() {
            let mut next = Vec::new();
            for module in frontier {
                for dep in graph.get(&module).into_iter().flatten() {
                    if dep == start {
                        found = Some(module.clone());
                        break 'walk;
                    }
                    if !came_from.contains_key(dep) {
                        came_from.insert(dep.clone(), module.clone());
                        next.push(dep.clone());
                    }
                }
            }
            frontier = next;
        }
        if let Some(last) = found {
            let mut circle = vec![last.clone()];
            let mut at = last;
            while let Some(before) = came_from.get(&at) {
                circle.push(before.clone());
                at = before.clone();
            }
            circle.reverse();
            circle.push(start.clone());
            reported.extend(circle.iter().cloned());
            circles.push(circle);
        }
    }
    circles
}
