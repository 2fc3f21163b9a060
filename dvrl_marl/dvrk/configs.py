"""The configuration files the dVRK's system program needs to stream an arm (and the system) to the robot seat.

Two streamers, each a ``mtsSocketStreamer`` the system program loads through its component manager (``-m FILE``):
one on the arm's ``Arm`` interface (what the seat reads and sends), one on the system's ``Main`` interface (power and
homing). Each has a configuration file of its own: the address it sends to (the seat's ports) and the commands it
carries, by name and cisst type. :func:`write_configs` writes the three files into a folder; ``dvrl-marl robot
--write-configs DIR`` calls it.
"""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["arm_streamer", "system_streamer", "component_manager", "write_configs"]

#: What the seat reads from an arm (name, cisst type), every streamer period.
ARM_READS = (("measured_cp", "prmPositionCartesianGet"), ("measured_js", "prmStateJoint"),
             ("jaw/measured_js", "prmStateJoint"), ("setpoint_cp", "prmPositionCartesianGet"),
             ("operating_state", "prmOperatingState"))
#: What it sends an arm.
ARM_WRITES = (("servo_cp", "prmPositionCartesianSet"), ("move_cp", "prmPositionCartesianSet"),
              ("jaw/servo_jp", "prmPositionJointSet"))
ARM_VOIDS = ("hold",)


def arm_streamer(ip: str, port: int) -> dict:
    """The arm's streamer: it sends to ``ip:port`` (the seat's ``--local-port``)."""
    return {"ip": ip, "port": str(port),
            "read-commands": [{"name": name, "type": kind} for name, kind in ARM_READS],
            "write-commands": [{"name": name, "type": kind} for name, kind in ARM_WRITES],
            "void-commands": list(ARM_VOIDS)}  # (operating_state read every period: no event handler needed)


def system_streamer(ip: str, port: int) -> dict:
    """The system's streamer: power and homing (void commands)."""
    # (a read command the streamer sends every period: its datagrams give the seat its address, and show it is up)
    return {"ip": ip, "port": str(port), "read-commands": [{"name": "calibration_mode", "type": "mtsBool"}],
            "void-commands": ["power_on", "power_off", "home"]}


def component_manager(arm: str, arm_file: str, system_file: str, period_s: float = 0.01) -> dict:
    """The component-manager file (``-m``): the two streamers, their files, and what each connects to."""

    def streamer(name, file):
        return {"shared-library": "sawSocketStreamer", "class-name": "mtsSocketStreamer",
                "constructor-arg": {"Name": name, "Period": period_s}, "configure-parameter": file}

    def connection(name, component, interface):
        return {"required": {"component": name, "interface": "Required"},
                "provided": {"component": component, "interface": interface}}

    return {"components": [streamer(f"seat_{arm}", arm_file), streamer("seat_system", system_file)],
            "connections": [connection(f"seat_{arm}", arm, "Arm"), connection("seat_system", "system", "Main")]}


def write_configs(folder, *, arm: str = "PSM1", ip: str = "127.0.0.1", arm_port: int = 10002,
                  system_port: int = 10004, period_s: float = 0.01) -> Path:
    """Writes ``streamer-<arm>.json``, ``streamer-system.json`` and ``manager-<arm>.json`` into ``folder``;
    returns the manager file's path (``-m`` takes it; run the system program from ``folder``)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    arm_file, system_file = f"streamer-{arm}.json", "streamer-system.json"
    (folder / arm_file).write_text(json.dumps(arm_streamer(ip, arm_port), indent=2) + "\n")
    (folder / system_file).write_text(json.dumps(system_streamer(ip, system_port), indent=2) + "\n")
    manager = folder / f"manager-{arm}.json"
    manager.write_text(json.dumps(component_manager(arm, arm_file, system_file, period_s), indent=2) + "\n")
    return manager
