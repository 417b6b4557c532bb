"""The environment's gymnasium id. gymnasium 1.x loads no plugin entry points (its registration.py imports a module
only for an id of the form "module:EnvId"), so `import expoctl.bench` registers it:

    gymnasium.make("expoctl.bench:expoctl/Exposure-v0", split="validation")   # imports expoctl.bench first
    gymnasium.make("expoctl/Exposure-v0")                                      # once expoctl.bench is imported
"""

ENV_ID = "expoctl/Exposure-v0"


def register_envs() -> None:
    """Register `expoctl/Exposure-v0` (the entry point is a string: the environment's module loads on make)."""
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="expoctl.bench.env:ExposureEnv")
