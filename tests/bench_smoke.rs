//! `hytrace bench --quick` runs and writes well-formed tables and JSON with agreement figures
//! (the peer section's too when built with the `fidget` feature).
//! Only the shape of the report is checked, never a time (speed is measured, not tested).

mod common;
use common::{assets, hytrace};

#[test]
fn quick_bench_writes_tables_and_json() {
    let dir = common::temp_dir("bench-smoke");
    let json = dir.path().join("bench.json");
    let out = hytrace()
        .args(["bench", "--quick", "--threads", "1,2", "--assets"])
        .arg(assets())
        .arg("--json")
        .arg(&json)
        .output()
        .expect("runs hytrace");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "bench failed:\n{stdout}\n{stderr}");
    for heading in [
        "## Meshes",
        "## SDF steppers",
        "## Scaling",
        "hit/miss agreement",
    ] {
        assert!(stdout.contains(heading), "no {heading:?} in:\n{stdout}");
    }
    // Every mesh table row has the nine columns.
    let rows: Vec<&str> = stdout
        .lines()
        .filter(|l| l.starts_with("| bunny | "))
        .filter(|l| l.matches('|').count() == 10)
        .collect();
    assert_eq!(rows.len(), 8, "4 ray sets × 2 thread counts:\n{stdout}");

    let text = std::fs::read_to_string(&json).expect("the JSON report was written");
    let v: serde_json::Value = serde_json::from_str(&text).expect("well-formed JSON");
    assert_eq!(v["quick"], true);
    assert!(v["machine"]["cpu"].is_string() && v["machine"]["commit"].is_string());
    assert!(v["machine"]["cores"].as_u64().unwrap() >= 1);
    let embree = v["machine"]["embree"].as_bool().unwrap();
    let mesh_rows = v["mesh"]["rows"].as_array().expect("mesh rows");
    assert_eq!(mesh_rows.len(), 8);
    let kinds: Vec<&str> = mesh_rows
        .iter()
        .map(|r| r["kind"].as_str().unwrap())
        .collect();
    for k in ["primary", "ao", "shadow", "incoherent"] {
        assert!(kinds.contains(&k), "{kinds:?}");
    }
    for r in mesh_rows {
        assert!(r["rays"].as_u64().unwrap() > 0, "{r}");
        assert!(r["ours_mrays"].as_f64().unwrap() > 0.0, "{r}");
        if embree {
            // Agreement is a fraction; the two tracers see the same rays.
            let a = r["agreement"].as_f64().expect("agreement with Embree");
            assert!((0.0..=1.0).contains(&a), "{r}");
            assert!(r["ratio"].as_f64().unwrap() > 0.0, "{r}");
        } else {
            assert!(r["agreement"].is_null(), "{r}");
        }
    }
    let sdf_rows = v["sdf"]["rows"].as_array().expect("SDF rows");
    assert!(sdf_rows.iter().any(|r| r["stepper"] == "Hart"));
    assert!(sdf_rows.iter().any(|r| r["stepper"] == "Segment"));
    assert!(
        sdf_rows
            .iter()
            .any(|r| r["stepper"].as_str().unwrap().starts_with("Relaxed"))
    );
    for r in sdf_rows {
        let same = r["same_hits"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&same), "{r}");
        let evals = r["evals_per_pixel"].as_f64().unwrap();
        assert!(evals > 0.0, "{r}");
        // Interval evaluations are counted among the evaluations, and only Segment makes any.
        let intervals = r["interval_evals_per_pixel"].as_f64().unwrap();
        assert!((0.0..=evals).contains(&intervals), "{r}");
        assert_eq!(intervals > 0.0, r["stepper"] == "Segment", "{r}");
    }
    let scaling = &v["scaling"];
    assert_eq!(
        scaling["sdf"].as_array().unwrap().len(),
        4,
        "2 sizes × BVH on/off"
    );
    assert!(!scaling["mesh"].as_array().unwrap().is_empty());
    for r in sdf_rows {
        assert!(r["ms_per_frame"].as_f64().unwrap() > 0.0, "{r}");
    }
    check_peer(&stdout, &v["peer"]);
}

/// The peer section: skipped with a clear line without the `fidget` feature; with it, a timing
/// row per model and thread count and an agreement row per model.
fn check_peer(stdout: &str, peer: &serde_json::Value) {
    assert!(stdout.contains("## SDF peer: fidget"), "{stdout}");
    if !cfg!(feature = "fidget") {
        assert!(
            stdout.contains("Skipped: needs the `fidget` feature"),
            "{stdout}"
        );
        assert!(peer["skipped"].is_string(), "{peer}");
        return;
    }
    assert!(peer["skipped"].is_null(), "{peer}");
    let models = peer["models"].as_array().expect("peer models");
    let names: Vec<&str> = models
        .iter()
        .map(|m| m["model"].as_str().unwrap())
        .collect();
    for n in [
        "gyroid sphere",
        "400 spheres",
        "smooth chain (60 links)",
        "twisted + bent",
        "showcase.ron",
    ] {
        assert!(names.contains(&n), "{names:?}");
    }
    assert_eq!(peer["rows"].as_array().unwrap().len(), 2 * models.len());
    for m in models {
        // At 64² fidget's 64 voxels along a ray miss some of the gyroid's thin walls: the
        // figures only have to be fractions here.
        for key in [
            "fidget_vm_agreement",
            "fidget_jit_agreement",
            "hytrace_agreement",
        ] {
            let a = m[key].as_f64().unwrap_or_else(|| panic!("{key} in {m}"));
            assert!((0.9..=1.0).contains(&a), "{key}: {m}");
        }
        assert!(m["truth"]["count"].as_u64().unwrap() > 0, "{m}");
    }
    for r in peer["rows"].as_array().unwrap() {
        for key in ["fidget_vm", "fidget_jit", "hytrace_first", "hytrace_steady"] {
            assert!(r[key]["median_ms"].as_f64().unwrap() > 0.0, "{key}: {r}");
        }
        assert!(r["steady_ratio"].as_f64().unwrap() > 0.0, "{r}");
    }
    let rows = stdout
        .lines()
        .filter(|l| l.starts_with("| gyroid sphere | ") && l.matches('|').count() == 10)
        .count();
    assert_eq!(rows, 2, "a timing row per thread count:\n{stdout}");
    // The GPU row is there; its figures depend on an adapter being found.
    assert!(peer["gpu"].is_object(), "{peer}");
    check_evaluators(stdout, &peer["evaluators"], &names);
}

/// The "Tape evaluators" table: per model, the six evaluators on both workloads, each with a
/// time per point and per instruction and its agreement with our scalar interpreter.
fn check_evaluators(stdout: &str, table: &serde_json::Value, names: &[&str]) {
    assert!(stdout.contains("### Tape evaluators"), "{stdout}");
    let models = table["models"].as_array().expect("evaluator models");
    let evaluated: Vec<&str> = models
        .iter()
        .map(|m| m["model"].as_str().unwrap())
        .collect();
    assert_eq!(evaluated, names, "a row block per peer model");
    // native code is measured where the CPU runs it
    let mut expected = vec![("hytrace eval8", 8), ("hytrace scalar", 1)];
    if hytrace::sdf::jit::available() {
        expected.push(("hytrace native", 8));
    }
    expected.extend([
        ("fidget VM", 8),
        ("fidget VM", 256),
        ("fidget JIT", 8),
        ("fidget JIT", 256),
    ]);
    for m in models {
        assert!(m["points"].as_u64().unwrap() > 0, "{m}");
        assert!(m["leaf_groups"].as_u64().unwrap() > 0, "{m}");
        assert!(m["tapes"].as_u64().unwrap() > 0, "{m}");
        // Specialised tapes are never longer than the whole ones they come from.
        let (spec, whole) = (
            m["mean_tape_specialised"].as_f64().unwrap(),
            m["mean_tape_whole"].as_f64().unwrap(),
        );
        assert!(spec > 0.0 && spec <= whole, "{m}");
        let figures = m["figures"].as_array().expect("figures");
        let kinds: Vec<(&str, u64)> = figures
            .iter()
            .map(|f| {
                (
                    f["evaluator"].as_str().unwrap(),
                    f["batch"].as_u64().unwrap(),
                )
            })
            .collect();
        assert_eq!(
            kinds,
            expected
                .iter()
                .map(|&(n, b)| (n, b as u64))
                .collect::<Vec<_>>(),
            "{}",
            m["model"]
        );
        for f in figures {
            for w in ["specialised", "whole"] {
                let t = &f[w];
                assert!(t["ns_per_point"].as_f64().unwrap() > 0.0, "{w}: {f}");
                assert!(t["best_ns_per_point"].as_f64().unwrap() > 0.0, "{w}: {f}");
                assert!(
                    t["ns_per_point_instruction"].as_f64().unwrap() > 0.0,
                    "{w}: {f}"
                );
                assert!(!t["runs_ms"].as_array().unwrap().is_empty(), "{w}: {f}");
                // Our packets give the scalar interpreter's bits; fidget's results agree to
                // the precision of its sin/cos/exp/ln (ours are polynomial approximations).
                let d = t["max_relative_difference"]
                    .as_f64()
                    .unwrap_or(f64::INFINITY);
                if f["evaluator"].as_str().unwrap().starts_with("hytrace") {
                    assert_eq!(d, 0.0, "{w}: {f}");
                } else {
                    assert!((0.0..=1e-3).contains(&d), "{w}: {f}");
                }
            }
        }
    }
    let rows = stdout
        .lines()
        .filter(|l| {
            l.starts_with("| gyroid sphere | fidget JIT | ") && l.matches('|').count() == 12
        })
        .count();
    assert_eq!(rows, 2, "a JIT row per batch size:\n{stdout}");
}

#[test]
fn bad_bench_arguments_are_errors() {
    for args in [
        vec!["bench", "--quick", "--size", "0x10"],
        vec!["bench", "--quick", "--only", "everything"],
        vec!["bench", "--quick", "--only", "peer", "--peer-size", "0"],
        vec![
            "bench",
            "--quick",
            "--mesh-scenes",
            "teapot",
            "--only",
            "mesh",
        ],
        vec![
            "bench",
            "--quick",
            "--only",
            "sdf",
            "--scenes",
            "/nonexistent/scenes",
        ],
    ] {
        let out = hytrace().args(&args).output().expect("runs hytrace");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} should fail");
        assert!(stderr.contains("error:"), "{args:?}: {stderr}");
    }
}
