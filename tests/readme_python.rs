//! The README's "Reading results in Python" snippets, run as written: `diffsound modes` writes
//! `out/bowl_modes.h5` (+ `.xdmf`) in a scratch folder (a small sphere instead of the bowl, for
//! time), and each ```python block of that section runs there under Debian's python3 with h5py
//! and meshio (`scripts/install-deps.sh`). A snippet that no longer matches the files fails
//! here, so the README cannot rot.

mod common;
use common::*;
use std::process::Command;
use std::time::Duration;

/// The ```python blocks of the README section titled `heading`.
fn python_blocks(readme: &str, heading: &str) -> Vec<String> {
    let start = readme
        .find(&format!("\n## {heading}\n"))
        .unwrap_or_else(|| panic!("README has no section '## {heading}'"));
    let section = &readme[start + 1..];
    let end = section[3..].find("\n## ").map_or(section.len(), |e| e + 3);
    let mut blocks = Vec::new();
    let mut rest = &section[..end];
    while let Some(open) = rest.find("```python\n") {
        let body = &rest[open + "```python\n".len()..];
        let close = body.find("\n```").expect("unclosed ```python block");
        blocks.push(body[..close + 1].to_string());
        rest = &body[close + 4..];
    }
    blocks
}

#[test]
fn readme_python_snippets_run_against_a_modes_file() {
    let readme = std::fs::read_to_string(repo().join("README.md")).unwrap();
    let blocks = python_blocks(&readme, "Reading results in Python");
    assert!(
        blocks.iter().any(|b| b.contains("import h5py"))
            && blocks.iter().any(|b| b.contains("import meshio")),
        "the section shows h5py and meshio: {blocks:?}"
    );

    let dir = scratch("readme_python");
    std::fs::create_dir_all(dir.join("out")).unwrap();
    let out = dir.join("out/bowl_modes.h5");
    let mesh = fixture("mesh/sphere_tet10_msh41_bin.msh");
    let run = mpirun(
        2,
        &[
            "modes",
            "--mesh",
            s(&mesh),
            "--modes",
            "6",
            "--out",
            s(&out),
        ],
        Duration::from_secs(300),
    );
    assert!(run.success(), "{}", run.describe());

    let python = std::env::var_os("DIFFSOUND_PYTHON").unwrap_or_else(|| "/usr/bin/python3".into());
    for block in &blocks {
        let result = Command::new(&python)
            .arg("-c")
            .arg(block)
            .current_dir(&dir)
            .output()
            .unwrap_or_else(|e| panic!("{}: {e}", python.to_string_lossy()));
        let (stdout, stderr) = (
            String::from_utf8_lossy(&result.stdout),
            String::from_utf8_lossy(&result.stderr),
        );
        assert!(
            result.status.success(),
            "README snippet failed:\n{block}\n--- stdout\n{stdout}\n--- stderr\n{stderr}"
        );
        eprintln!("{stdout}");
        assert!(!stdout.trim().is_empty(), "the snippet prints what it read");
    }
}

#[test]
fn the_section_parser_finds_blocks_only_in_its_section() {
    let text = "# t\n\n## A\n```python\nprint(1)\n```\n\n## B\n```python\nprint(2)\n```\n\n```python\nprint(3)\n```\n## C\n```python\nprint(4)\n```\n";
    assert_eq!(python_blocks(text, "B"), ["print(2)\n", "print(3)\n"]);
    assert_eq!(python_blocks(text, "C"), ["print(4)\n"]);
}
