//! The committed on-target vectors are exactly what their generator makes
//! now (so the firmware never tests against stale reference numbers).

#[test]
fn committed_vectors_are_current() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join(host_tests::target_vectors::PATH);
    let committed = std::fs::read_to_string(&path).expect("vectors file");
    assert!(
        committed == host_tests::target_vectors::render(),
        "{} is stale: run `cargo run -p host-tests --bin gen-target-vectors`",
        path.display()
    );
}
