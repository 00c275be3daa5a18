"""The robot runtime must stay lean: importing it pulls in no scipy, matplotlib or host code."""
import json
import subprocess
import sys

FORBIDDEN = ("scipy", "matplotlib", "tools", "skimage", "tqdm")


def test_onboard_imports_nothing_from_the_host_side():
    code = (
        "import importlib, json, pkgutil, sys\n"
        "import onboard\n"
        "for m in pkgutil.iter_modules(onboard.__path__):\n"
        "    importlib.import_module('onboard.' + m.name)\n"
        "print(json.dumps(sorted(sys.modules)))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True)
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    bad = [m for m in loaded if m.split(".")[0] in FORBIDDEN]
    assert not bad, f"onboard imported host-side modules: {bad}"
