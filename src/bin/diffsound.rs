fn main() {
    diffsound::cli::main();
}
