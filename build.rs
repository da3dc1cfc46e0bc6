//! Compiles the C++ half of the bridge (`cpp/`, one translation unit per PCL module) with
//! cxx-build against the Debian PCL 1.13 found through pkg-config.
//!
//! PCL's class templates are compiled from PCL's own headers (`PCL_NO_PRECOMPILE`, PCL's
//! documented mode for custom point types) rather than linked from Debian's precompiled
//! instantiations: loading libpcl_features, _segmentation, _sample_consensus and _filters costs
//! every process about 60 ms of symbol relocations at start (230 000 of them, 117 000 in
//! libpcl_features alone), whichever stage runs. Only libpcl_common is linked; the one
//! non-template function the templates need from libpcl_features, `pcl::computePairFeatures`, is
//! looked up in it when FPFH first runs (`cpp/features.cpp`). Debian compiled PCL for the
//! baseline x86-64 (SSE2, no FMA) with OpenMP, and so is the bridge: the same arithmetic.

use std::path::Path;

/// PCL modules whose headers the bridge compiles, as pkg-config names (Debian's `libpcl-dev`
/// ships `pcl_*.pc`).
const PCL_MODULES: &[&str] = &[
    "pcl_common",
    "pcl_search",
    "pcl_kdtree",
    "pcl_filters",
    "pcl_features",
    "pcl_sample_consensus",
    "pcl_segmentation",
    "pcl_registration",
];

/// Libraries linked (pkg-config names).
const LINKED: &[&str] = &["pcl_common", "liblz4"];

/// C++ sources, split by PCL module so they compile in parallel and rebuild independently;
/// the longest to compile first.
const SOURCES: &[&str] = &[
    "cpp/registration.cpp",
    "cpp/segmentation.cpp",
    "cpp/features.cpp",
    "cpp/common.cpp",
    "cpp/filters.cpp",
];

const HEADERS: &[&str] = &["cpp/include/binpick_pcl.h", "cpp/include/internal.h"];

/// The reference pipeline (thesis Algorithms 1 and 2 written directly against PCL, one call per
/// scene). Compiled only with the feature `reference`: the CLI and the tests build it, a
/// controller need not.
const REFERENCE_SOURCES: &[&str] = &["cpp/reference/pipeline.cpp"];

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=src/ffi.rs");
    for f in SOURCES.iter().chain(HEADERS) {
        println!("cargo:rerun-if-changed={f}");
    }
    for f in REFERENCE_SOURCES {
        println!("cargo:rerun-if-changed={f}");
    }
    println!("cargo:rerun-if-env-changed=PKG_CONFIG_PATH");
    println!("cargo:rerun-if-env-changed=RUSTC_WORKSPACE_WRAPPER");

    let mut include_dirs = Vec::new();
    for module in PCL_MODULES {
        match pkg_config::Config::new()
            .atleast_version("1.13")
            .cargo_metadata(false)
            .probe(module)
        {
            Ok(lib) => include_dirs.extend(lib.include_paths),
            Err(e) => {
                eprintln!(
                    "\nerror: the PCL development files were not found ({module}: {e}).\n\
                     binpick needs PCL >= 1.13 with Eigen and FLANN. On Debian 12 install them with\n\
                     \n    sudo apt-get install -y libpcl-dev pkg-config\n\n\
                     or run ./scripts/setup, which installs what is missing.\n"
                );
                std::process::exit(1);
            }
        }
    }
    // Linked: PCL's non-template core, and LZ4, which FLANN's headers call.
    for lib in LINKED {
        if let Err(e) = pkg_config::Config::new().probe(lib) {
            eprintln!(
                "\nerror: {lib} was not found ({e}).\n\
                 Install it with: sudo apt-get install -y libpcl-dev pkg-config (or ./scripts/setup)\n"
            );
            std::process::exit(1);
        }
    }
    include_dirs.sort();
    include_dirs.dedup();
    // The compiler's default directory must stay last in its search order (`#include_next`).
    include_dirs.retain(|d| d != Path::new("/usr/include"));

    // Clippy only checks the Rust side (the bridge's Rust half is cxx's proc macro) and links
    // nothing, so the C++ is not compiled under clippy-driver, which Cargo names in the
    // documented build-script variable RUSTC_WORKSPACE_WRAPPER. Saves ~2 min per clippy run.
    if std::env::var("RUSTC_WORKSPACE_WRAPPER").is_ok_and(|w| w.contains("clippy-driver")) {
        return;
    }

    // One library, its translation units compiled at once on the jobserver's cores (cc's
    // `parallel`); the reference pipeline only with the feature `reference` (on for the CLI and
    // the tests; a controller need not build it).
    let mut sources: Vec<&str> = SOURCES.to_vec();
    if std::env::var_os("CARGO_FEATURE_REFERENCE").is_some() {
        sources.extend(REFERENCE_SOURCES);
    }
    let mut build = cxx_build::bridge("src/ffi.rs");
    configure(&mut build, &sources, &include_dirs);
    build.compile("binpick_pcl_bridge");
    // PCL's OpenMP estimators (NormalEstimationOMP, FPFHEstimationOMP) run their loops on it.
    println!("cargo:rustc-link-lib=gomp");
}

/// Sources and flags of the library. PCL and Eigen headers are noisy, so they are
/// system includes; our own code is still compiled with -Wall.
fn configure(build: &mut cc::Build, sources: &[&str], include_dirs: &[std::path::PathBuf]) {
    build
        .files(sources)
        .include(Path::new("cpp/include"))
        .std("c++17")
        .flag("-Wall")
        // PCL's arithmetic as Debian compiled it: a float multiply-add never fused into one
        // rounding (only possible where FMA is enabled), so counts reproduce PCL's exactly.
        .flag("-ffp-contract=off")
        .define("PCL_NO_PRECOMPILE", None)
        // PCL's own OpenMP loops (its OMP estimators, RANSAC's region) as Debian built them;
        // the reference pipeline's `#pragma omp parallel for` over clusters (thesis 4.4).
        .flag("-fopenmp")
        .flag_if_supported("-Wno-deprecated-declarations")
        // GCC 12 false positive inside Eigen (inlined aligned_free), not in our code.
        .flag_if_supported("-Wno-use-after-free");
    for dir in include_dirs {
        build.flag(format!("-isystem{}", dir.display()));
    }
}
