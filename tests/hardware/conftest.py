"""Two emulated GigE Vision cameras (`arv-fake-gv-camera-0.8`) on loopback, in a private network namespace.

Why a namespace: Aravis finds GigE cameras by broadcasting a discovery packet on every network interface. Inside a
fresh namespace the only interface is `lo`, so neither the emulators nor the code under test can send anything beyond
127.0.0.0/8. Each emulator needs its own address: camera A listens on 127.0.0.1, camera B on 127.0.0.2 (added to the
namespace's `lo`, which disappears with the namespace). Everything that talks to a camera runs inside the namespace
as a subprocess (`emulators.run([...])`): the CLI exactly as a user runs it, or a short Python check.

Needs root (namespaces), iproute2, aravis-tools and PyGObject with Aravis 0.8 (.ci/run installs them). Without them
the tests skip — except when EXPOCTL_REQUIRE_CAMERA_TESTS=1 (CI sets it), where a missing piece fails the run.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import pytest

EMULATOR = "arv-fake-gv-camera-0.8"
ADDRESSES = ("127.0.0.1", "127.0.0.2")


def _missing() -> str | None:
    if os.geteuid() != 0:
        return "needs root (network namespace for the emulated cameras)"
    for exe in ("ip", EMULATOR):
        if shutil.which(exe) is None:
            return f"{exe} not installed (apt-get install iproute2 aravis-tools)"
    probe = subprocess.run([sys.executable, "-c", "import gi; gi.require_version('Aravis', '0.8'); "
                                                  "from gi.repository import Aravis"], capture_output=True, text=True)
    if probe.returncode != 0:
        return ("PyGObject/Aravis 0.8 not importable (apt-get install gir1.2-aravis-0.8; pip install "
                "'expoctl[camera]'): " + (probe.stderr.strip().splitlines() or ["?"])[-1])
    return None


@dataclass
class Emulators:
    ns: str
    serials: tuple[str, str]
    procs: list = field(default_factory=lambda: [None, None])

    def ids(self) -> tuple[str, str]:
        return self.serials

    def start(self, i: int) -> None:
        """(Re)start emulator i (0 = camera A on 127.0.0.1, 1 = camera B on 127.0.0.2)."""
        self.stop(i)
        self.procs[i] = subprocess.Popen(["ip", "netns", "exec", self.ns, EMULATOR, "-i", ADDRESSES[i],
                                          "-s", self.serials[i]], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:  # ready once it listens for GVCP on its address (a loaded CI is slow)
            if self.procs[i].poll() is not None:
                raise RuntimeError(f"emulator {self.serials[i]} exited at once (rc {self.procs[i].returncode})")
            ss = subprocess.run(["ip", "netns", "exec", self.ns, "ss", "-Hlun"], capture_output=True, text=True)
            if f"{ADDRESSES[i]}:3956" in ss.stdout:
                return
            time.sleep(0.1)
        raise RuntimeError(f"emulator {self.serials[i]} not listening on {ADDRESSES[i]}:3956 after 20 s")

    def stop(self, i: int) -> None:
        p = self.procs[i]
        if p is not None and p.poll() is None:
            p.send_signal(signal.SIGKILL)  # the way a camera disappears: no goodbye
            p.wait(timeout=10)
        self.procs[i] = None

    def command(self, argv: list[str]) -> list[str]:
        return ["ip", "netns", "exec", self.ns, *argv]

    def run(self, argv: list[str], timeout: float = 120.0) -> subprocess.CompletedProcess:
        return subprocess.run(self.command(argv), capture_output=True, text=True, timeout=timeout)

    def expoctl(self, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess:
        return self.run([sys.executable, "-m", "expoctl.cli", *args], timeout=timeout)

    def popen_expoctl(self, *args: str) -> subprocess.Popen:
        return subprocess.Popen(self.command([sys.executable, "-m", "expoctl.cli", *args]), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)


@pytest.fixture(scope="module")
def emulators():
    why = _missing()
    if why:
        if os.environ.get("EXPOCTL_REQUIRE_CAMERA_TESTS") == "1":
            pytest.fail(f"camera tests required (EXPOCTL_REQUIRE_CAMERA_TESTS=1) but {why}")
        pytest.skip(why)
    tag = uuid.uuid4().hex[:6]
    ns = f"expoctl-test-{tag}"
    subprocess.run(["ip", "netns", "add", ns], check=True)
    emu = Emulators(ns, (f"EXPOCTL{tag}A", f"EXPOCTL{tag}B"))
    try:
        subprocess.run(["ip", "netns", "exec", ns, "ip", "link", "set", "lo", "up"], check=True)
        subprocess.run(["ip", "netns", "exec", ns, "ip", "addr", "add", f"{ADDRESSES[1]}/8", "dev", "lo"], check=True)
        emu.start(0)
        emu.start(1)
        yield emu
    finally:
        emu.stop(0)
        emu.stop(1)
        subprocess.run(["ip", "netns", "delete", ns], check=False)


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory) -> Path:
    """A small network built with the library's model class and saved the way `train` saves one (+ ONNX)."""
    import torch

    from expoctl.net.model import ExposureNet, ModelConfig
    from expoctl.net.checkpoint import CHECKPOINT_FORMAT, export_onnx

    cfg = ModelConfig(input_size=(24, 32), conv_kernels=(3, 3, 3), pool=2, conv_widths=(4, 4, 4, 4),
                      fc_widths=(4, 4, 4), exposure_scale="log", output="residual")
    torch.manual_seed(0)
    model = ExposureNet(cfg).eval()
    out = tmp_path_factory.mktemp("model")
    ckpt = {"format": CHECKPOINT_FORMAT, "model_config": cfg.to_dict(), "state_dict": model.state_dict(),
            "store_hw": [48, 64], "input_hw": [24, 32]}
    torch.save(ckpt, out / "controller.pt")
    export_onnx(model, out / "controller.onnx")
    return out / "controller.pt"
