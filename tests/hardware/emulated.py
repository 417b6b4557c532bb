"""Settings every emulated-camera test uses (a module of its own: `conftest` is not importable by a unique name)."""

#: how the emulator's raw gain maps to dB for expoctl (see expoctl.hardware.aravis: 6 dB ≈ its brightness per step)
GAIN_DB_PER_RAW = 6.0


def camera_args() -> list[str]:
    """The options every emulator run uses: 640×480, the emulator's gain scale, a camera lost after 1.5 s."""
    return ["--gain-db-per-raw", str(GAIN_DB_PER_RAW), "--width", "640", "--height", "480", "--timeout-s", "1.5"]
