fn main() {
    std::process::exit(brdfpack::cli::main());
}
