"""Download the wheels that blender_manifest.toml lists (for `make extension`).

The manifest is the single source of truth: each listed file name is parsed
into project, version, Python tag and platform tag, and fetched with
``pip download`` for exactly that platform.  Files already present are kept.
"""
import argparse
import pathlib
import subprocess
import sys
import tomllib

ROOT = pathlib.Path(__file__).resolve().parent.parent


def wheel_requests(manifest_path):
    manifest = tomllib.loads(manifest_path.read_text())
    for entry in manifest.get("wheels", []):
        name = pathlib.Path(entry).name
        project, version, python_tag, _abi, platform = name[:-len(".whl")].split("-")
        yield name, project, version, python_tag, platform.split(".")[-1]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dest", default="wheels")
    parser.add_argument("--manifest", default=str(ROOT / "blender_manifest.toml"))
    parser.add_argument("--only", default="", help="comma-separated wheel file names (default: all listed)")
    args = parser.parse_args(argv)
    dest = (ROOT / args.dest).resolve()
    dest.mkdir(parents=True, exist_ok=True)
    missing = []
    only = set(filter(None, args.only.split(",")))
    for name, project, version, python_tag, platform in wheel_requests(pathlib.Path(args.manifest)):
        if (only and name not in only) or (dest / name).exists():
            continue
        subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--only-binary=:all:", "--no-deps",
                        "--platform", platform, "--python-version", python_tag[2:], "--implementation", "cp",
                        "-d", str(dest), f"{project}=={version}"], check=True)
        if not (dest / name).exists():
            missing.append(name)
    if missing:
        print("fetch_wheels: pip did not produce " + ", ".join(missing), file=sys.stderr)
        return 1
    print(f"fetch_wheels: {len(list(dest.glob('*.whl')))} wheels in {dest}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
