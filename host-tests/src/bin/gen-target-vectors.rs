//! Writes the on-target parity vectors (see `host_tests::target_vectors`).

fn main() -> std::io::Result<()> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let path = root.join(host_tests::target_vectors::PATH);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    std::fs::write(&path, host_tests::target_vectors::render())?;
    println!("wrote {}", path.display());
    Ok(())
}
