#!/usr/bin/env bash
# Same bytes from two builds (issue 24: a restructuring must not change any output).
#   scripts/same_bytes.sh OLD_BIN NEW_BIN
# Runs the default `pack`, `tabulate` on every grid kind, every `convert` format and
# `compress` with codecs with both binaries (each in its own directory, same relative paths)
# and `cmp`s every output. Exit 0 when all are identical, 1 otherwise.
set -euo pipefail
[ $# -eq 2 ] || { echo "usage: $0 OLD_BIN NEW_BIN" >&2; exit 2; }
old=$(realpath "$1")
new=$(realpath "$2")
root=$(cd "$(dirname "$0")/.." && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# Inputs both runs share: a model spec file (@file.json), optical constants (CSV), an RGL file.
mkdir -p "$tmp/in"
cp "$root/fixtures/spectral/test-conductor.csv" "$tmp/in/nk.csv"
cp "$root/fixtures/rgl/tiny.bsdf" "$tmp/in/tiny.bsdf"
echo '{"model": "ggx", "alpha": 0.3, "fresnel": {"type": "schlick", "f0": [0.9, 0.6, 0.3]}}' >"$tmp/in/spec.json"

# Each line: an output name and the arguments after the binary (OUT is replaced by the path).
jobs=(
    "pack.bpk|pack -o OUT"
    "pack-v.txt|pack -o pack2.bpk -v"
    "tab-merl.bpk|tabulate ggx:alpha=0.2,fresnel=au --grid merl -o OUT"
    "tab-hd3.bpk|tabulate beckmann:alpha=0.3 --grid halfdiff3:32x16x32 -o OUT"
    "tab-hd4.bpk|tabulate ggx:alpha_x=0.1,alpha_y=0.3,fresnel=au --grid halfdiff4:16 -o OUT"
    "tab-s4.bpk|tabulate ward:alpha_x=0.1,alpha_y=0.25 --grid spherical4:16x32x16x32 -o OUT"
    "tab-s3.bpk|tabulate lambert:albedo=0.8/0.5/0.2 --grid spherical3:16x16x32 -o OUT"
    "tab-s3-sqrt.bpk|tabulate phong:exponent=20 --grid spherical3:24x24x48,warp=sqrt,at=edge -o OUT"
    "tab-thmax.bpk|tabulate ggx:alpha=0.2 --grid halfdiff3:32x16x32,theta-max=70 -o OUT"
    "tab-file.bpk|tabulate @in/spec.json --grid halfdiff3:32x16x32 -o OUT"
    "tab-nk.bpk|tabulate ggx:alpha=0.25,fresnel=conductor,nk=@in/nk.csv,wavelengths_nm=450/550/650 --grid halfdiff3:32x16x32 -o OUT"
    "tab-htsg.bpk|tabulate htsg:sigma0=0.3,tau=2.5 --grid halfdiff3:16x8x16 -o OUT"
    "tab-htsg-nk.bpk|tabulate htsg:sigma0=0.3,nk=@in/nk.csv,wavelengths_nm=450/550/650 --grid halfdiff3:16x8x16 -o OUT"
    "conv-spectral.bpk|convert tab-nk.bpk -o OUT"
    "tab-rgl.bpk|tabulate in/tiny.bsdf --grid spherical3:8x8x16 --allow-anisotropic -o OUT"
    "tab-stdout.bpk|tabulate lambert:albedo=0.5 --grid spherical3:8x8x16 -o -"
    "conv-native.bpk|convert tab-merl.bpk -o OUT"
    "conv.exr|convert tab-hd3.bpk -o OUT"
    "conv.binary|convert tab-merl.bpk -o OUT"
    "conv-model.binary|convert lambert:albedo=0.8/0.5/0.2 -o OUT"
    "conv.bsdf|convert tab-s3.bpk -o OUT"
    "conv.mbsdf|convert lambert:albedo=0.8/0.5/0.2 --grid spherical3:16x16x32 -o OUT"
    "conv-regrid.bpk|convert tab-hd3.bpk --grid spherical3:16x16x32 -o OUT"
    "comp-lossless.bpk|compress tab-merl.bpk -o OUT"
    "comp-dct.bpk|compress tab-merl.bpk --codec dct:step=0.02 -o OUT"
    "comp-uniform.bpk|compress tab-hd3.bpk --codec uniform:bits=12 -o OUT"
    "comp-f16.bpk|compress tab-s4.bpk --codec f16 -o OUT"
    "comp-budget.bpk|compress tab-merl.bpk --max-error log_rmse=0.02 -o OUT"
    "eval.txt|eval tab-merl.bpk --wi-deg 30,0 --wo-deg 45,180"
    "check.txt|check comp-dct.bpk --against tab-merl.bpk"
    "man.roff|man"
)
# Every subcommand's help (the CLI's value names and their help texts included).
for sub in pack tabulate check compress convert inspect eval props models plot bench build completions; do
    jobs+=("help-$sub.txt|$sub --help")
done

run_all() {
    local dir=$2
    mkdir -p "$dir/bin"
    # The same file name for both (help texts show it).
    cp "$1" "$dir/bin/brdfpack"
    local bin=$dir/bin/brdfpack
    cp -r "$tmp/in" "$dir/in"
    for job in "${jobs[@]}"; do
        local name=${job%%|*} args=${job#*|}
        args=${args//OUT/$name}
        # shellcheck disable=SC2086
        local rc=0
        (cd "$dir" && "$bin" $args >"$dir/$name.stdout" 2>"$dir/$name.stderr") || rc=$?
        echo "$rc" >"$dir/$name.rc"
    done
}

run_all "$old" "$tmp/old"
run_all "$new" "$tmp/new"

same=0
differ=0
for job in "${jobs[@]}"; do
    name=${job%%|*}
    for f in "$name" "$name.stdout" "$name.rc"; do
        if [ ! -e "$tmp/old/$f" ] && [ ! -e "$tmp/new/$f" ]; then
            continue
        fi
        if cmp -s "$tmp/old/$f" "$tmp/new/$f"; then
            same=$((same + 1))
        else
            echo "DIFFER: $f (${job#*|})"
            differ=$((differ + 1))
        fi
    done
    if [ "$(cat "$tmp/old/$name.rc")" != 0 ]; then
        echo "note: $name exited $(cat "$tmp/old/$name.rc") with the old binary: $(head -c 300 "$tmp/old/$name.stderr")"
    fi
done
echo "same_bytes: $same identical, $differ different"
[ "$differ" -eq 0 ]
