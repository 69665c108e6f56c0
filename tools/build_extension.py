"""Build the PHRT extension zip(s) with the wheels they need.

    python tools/build_extension.py [--platforms all|linux-x64,windows-x64,...] [--out dist]

The wheels listed in blender_manifest.toml are fetched into wheels/ (a cache,
ignored by git).  For a subset of platforms the source is staged in a temporary
folder with a manifest narrowed to those platforms and their wheels, because
Blender's ``blender_ext.py build`` has no switch for a single platform.  Then
``validate`` and ``build --split-platforms`` (the script that ships in the bpy
wheel) produce one zip per platform.
"""
import argparse
import pathlib
import re
import shutil
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tools"))
import fetch_wheels  # noqa: E402

PLATFORM_TAGS = {
    "linux-x64": re.compile(r"manylinux.*_x86_64"),
    "windows-x64": re.compile(r"win_amd64"),
    "macos-arm64": re.compile(r"macosx_.*_arm64"),
    "macos-x64": re.compile(r"macosx_.*_x86_64"),
}


def blender_ext_script() -> pathlib.Path:
    import importlib.util
    spec = importlib.util.find_spec("bpy")  # locates the wheel without starting Blender
    if spec is None or spec.origin is None:
        raise SystemExit("the bpy module is not installed: run 'make venv' first")
    base = pathlib.Path(spec.origin).parent
    matches = sorted(base.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not matches:
        raise SystemExit("blender_ext.py not found in the bpy wheel")
    return matches[-1]


def staged_source(platforms, manifest_text, stage):
    """Copy the extension's files to ``stage`` with a manifest for ``platforms`` only."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT, check=True,
                           capture_output=True, text=True).stdout.split()
    for name in files:
        source = ROOT / name
        if source.is_file():
            target = stage / name
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)
    wheel_lines = []
    for line in manifest_text.splitlines():
        match = re.search(r'"\./wheels/([^"]+\.whl)"', line)
        if match and not any(PLATFORM_TAGS[p].search(match.group(1)) for p in platforms):
            continue
        wheel_lines.append(line)
    text = "\n".join(wheel_lines) + "\n"
    text = re.sub(r"^platforms = .*$", "platforms = [" + ", ".join(f'"{p}"' for p in platforms) + "]", text,
                  flags=re.MULTILINE)
    (stage / "blender_manifest.toml").write_text(text)
    (stage / "wheels").mkdir(exist_ok=True)
    for wheel in (ROOT / "wheels").glob("*.whl"):
        if any(PLATFORM_TAGS[p].search(wheel.name) for p in platforms):
            shutil.copy2(wheel, stage / "wheels" / wheel.name)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--platforms", default="all")
    parser.add_argument("--out", default=str(ROOT / "dist"))
    args = parser.parse_args(argv)
    platforms = list(PLATFORM_TAGS) if args.platforms == "all" else args.platforms.split(",")
    unknown = [p for p in platforms if p not in PLATFORM_TAGS]
    if unknown:
        raise SystemExit(f"unknown platform(s) {unknown}: use {', '.join(PLATFORM_TAGS)}")
    manifest_text = (ROOT / "blender_manifest.toml").read_text()
    wanted = [name for name, *_ in fetch_wheels.wheel_requests(ROOT / "blender_manifest.toml")
              if any(PLATFORM_TAGS[p].search(name) for p in platforms)]
    if fetch_wheels.main(["--dest", "wheels", "--only", ",".join(wanted)]) != 0:
        return 1
    out = pathlib.Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    script = blender_ext_script()
    with tempfile.TemporaryDirectory(prefix="phrt-build-") as temp:
        stage = pathlib.Path(temp)
        staged_source(platforms, manifest_text, stage)
        subprocess.run([sys.executable, str(script), "validate", str(stage)], check=True)
        subprocess.run([sys.executable, str(script), "build", "--source-dir", str(stage), "--output-dir", str(out),
                        "--split-platforms"], check=True)
    for platform in platforms:
        print(f"built {next(out.glob('phrt-*-' + platform.replace('-', '_') + '.zip'))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
