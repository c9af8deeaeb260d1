# Sourced by the scripts: where cargo builds a workspace.
#
#   cargo_target_dir [DIR]   prints the target directory of the workspace at DIR (default: the
#                            current one), honouring CARGO_TARGET_DIR and build.target-dir
#   release_trainer          prints the release `trainer` binary of the root workspace, building
#                            it first if it is missing
cargo_target_dir() {
    (cd "${1:-.}" && cargo metadata --format-version 1 --no-deps |
        python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])')
}

release_trainer() {
    local dir
    dir=$(cargo_target_dir) || return 1
    [ -x "$dir/release/trainer" ] || cargo build --release -p dex-trainer --bin trainer >&2 || return 1
    echo "$dir/release/trainer"
}
