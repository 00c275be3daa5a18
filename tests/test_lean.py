"""The layers run one way, and the robot runtime stays lean.

btf <- radio <- onboard (with hal, which stands alone) <- tools: a module may import only from
its own package and the ones it stands on (read from the source with ast, function-level
imports included), so no package cycle exists. Importing every onboard module pulls in no
scipy, matplotlib, scikit-image, tqdm, OpenCV or host code.
"""
import ast
import json
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parent.parent
PACKAGES = ("btf", "radio", "hal", "onboard", "tools")
ALLOWED = {
    "btf": set(),
    "radio": {"btf"},
    "hal": set(),
    "onboard": {"btf", "radio", "hal"},
    "tools": {"btf", "radio", "hal", "onboard"},
}
FORBIDDEN_ONBOARD = ("scipy", "matplotlib", "tools", "skimage", "tqdm", "cv2")


def imports_of(path: pathlib.Path) -> set[str]:
    """The top-level packages of everything a module imports, anywhere in its body."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module.split(".")[0])
    return out


@pytest.mark.parametrize("package", PACKAGES)
def test_a_package_imports_only_what_it_stands_on(package):
    wrong = {}
    for path in sorted((ROOT / package).rglob("*.py")):
        bad = (imports_of(path) & set(PACKAGES)) - ALLOWED[package] - {package}
        if bad:
            wrong[str(path.relative_to(ROOT))] = sorted(bad)
    assert not wrong, f"{package} imports from a higher layer: {wrong}"


def test_the_layers_have_no_cycle():
    # each package's allowed set only names packages below it
    order = {p: i for i, p in enumerate(("btf", "radio", "hal", "onboard", "tools"))}
    for package, below in ALLOWED.items():
        assert all(order[b] < order[package] for b in below), package


def test_onboard_imports_nothing_from_the_host_side():
    code = (
        "import importlib, json, pkgutil, sys\n"
        "import onboard\n"
        "for m in pkgutil.walk_packages(onboard.__path__, 'onboard.'):\n"
        "    if not m.name.endswith('__main__'): importlib.import_module(m.name)\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    bad = [m for m in loaded if m.split(".")[0] in FORBIDDEN_ONBOARD]
    assert not bad, f"onboard imported host-side or heavy modules: {bad}"


def test_reading_image_files_loads_none_of_the_robots_devices():
    code = "import json, sys\nimport hal.image_files\nprint(json.dumps(sorted(sys.modules)))\n"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert not [m for m in loaded if m.startswith("hal.") and m != "hal.image_files"], loaded


def test_the_shared_package_stands_on_numpy_and_the_standard_library_alone():
    code = (
        "import importlib, json, pkgutil, sys\n"
        "import btf\n"
        "for m in pkgutil.walk_packages(btf.__path__, 'btf.'):\n"
        "    if not m.name.endswith('__main__'): importlib.import_module(m.name)\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    loaded = {m.split(".")[0] for m in json.loads(out.stdout.strip().splitlines()[-1])}
    others = loaded - set(sys.stdlib_module_names) - {"btf", "numpy"} - {m for m in loaded if m.startswith("_")}
    assert not others, f"btf imported more than numpy and the standard library: {sorted(others)}"


def test_the_radio_packets_load_no_fitter():
    code = "import json, sys, radio.packets, radio.link\nprint(json.dumps(sorted(sys.modules)))\n"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert not [m for m in loaded if m.split(".")[0] in ("onboard", "hal", "tools")]
