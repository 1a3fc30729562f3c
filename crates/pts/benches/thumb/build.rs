fn main() {
    let dir = std::env::var("CARGO_MANIFEST_DIR").unwrap_or_default();
    println!("cargo:rustc-link-arg=-T{dir}/bench.x");
    println!("cargo:rerun-if-changed=bench.x");
}
