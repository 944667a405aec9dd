//! Generates raw PETSc/SLEPc bindings with bindgen over Debian's headers.
//!
//! Facts this relies on (see ../shared/notes/stack.md):
//! - `PETSc.pc` carries no MPI include directory and the only `mpi.h` on the default path is
//!   MUMPS's dummy (`/usr/include/mumps_seq`), so the OpenMPI include dirs go to clang FIRST.
//! - MPI types are blocklisted so that rsmpi's `mpi::ffi` types (`MPI_Comm`, …) are reused and a
//!   communicator's `as_raw()` goes straight into PETSc calls.
use std::env;
use std::path::PathBuf;

fn include_dirs(lib: &pkg_config::Library) -> Vec<String> {
    lib.include_paths
        .iter()
        .map(|p| format!("-I{}", p.display()))
        .collect()
}

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=src/petsc/wrapper.h");

    let ompi = pkg_config::Config::new()
        .cargo_metadata(false)
        .probe("ompi")
        .expect("pkg-config could not find OpenMPI (`ompi`): run scripts/install-deps.sh");
    let slepc = pkg_config::Config::new()
        .probe("slepc")
        .expect("pkg-config could not find SLEPc: run scripts/install-deps.sh");

    let mut clang_args = include_dirs(&ompi);
    clang_args.extend(include_dirs(&slepc));

    let bindings = bindgen::Builder::default()
        .header("src/petsc/wrapper.h")
        .clang_args(clang_args)
        .allowlist_function(
            "(Petsc|Mat|Vec|KSP|PC|EPS|ST|BV|DS|RG|Slepc|IS|ISLocalToGlobal|VecScatter|Options).*",
        )
        .allowlist_type(
            "(Petsc|Mat|Vec|KSP|PC|EPS|ST|BV|Slepc|IS|InsertMode|NormType|ScatterMode|_p_).*",
        )
        .allowlist_var("(PETSC|MAT|VEC|KSP|PC|EPS|ST|SLEPC).*")
        .blocklist_type("(MPI_|ompi_).*")
        .blocklist_function("(MPI_|ompi_).*")
        .blocklist_item("(MPI_|ompi_).*")
        .raw_line("use mpi::ffi::{MPI_Comm, MPI_Datatype, MPI_Op, MPI_Group};")
        .raw_line("#[allow(unused_imports)] use mpi::ffi::*;")
        .default_enum_style(bindgen::EnumVariation::Consts)
        .layout_tests(false)
        .generate_comments(false)
        .derive_debug(false)
        .parse_callbacks(Box::new(bindgen::CargoCallbacks::new()))
        .generate()
        .expect("bindgen failed over petsc.h/slepceps.h");

    let out = PathBuf::from(env::var("OUT_DIR").unwrap()).join("petsc_bindings.rs");
    bindings
        .write_to_file(out)
        .expect("could not write bindings");
}
