"""The plant-can FMU's spec: the plant FMU (:mod:`.plant_spec`) behind the vehicle's CAN bus. Its inputs and
outputs are CAN frames on one FMI-LS-BUS bus terminal ``CAN`` (network abstraction, FMI-LS-BUS 1.0 "CAN"):
the master's NMT, SYNC and RPDOs in through ``CAN.Rx_Data``, the nodes' boot-up, TPDO and EMCY frames out
through ``CAN.Tx_Data``, each a clocked Binary variable of MIME type
``application/org.fmi-standard.fmi-ls-bus.can; version="1.0.0"``. Behind the terminal: the four CiA 402
drives and two CiA 406 steering encoders of ``qomni emulate`` (PDO path, lock-step: C sources
``fmu/c/plant_can``), in front of the same hybrid plant (``fmu/c/plant``). FMI 3.0 only (clocks, Binary).

The plant's pose, velocity, steering and encoder outputs stay as Float64 outputs, and the torques the
drives apply are outputs (``motor_torque.*``, N m motor side), so a co-simulation can watch the plant and
compare it with the signal-level FMU.
"""
from __future__ import annotations

from dataclasses import replace

from . import codegen
from .feedforward_spec import DEFAULT_EPS
from .plant_spec import PLANT_DESCRIPTION, PLANT_N_STATES, plant_variables
from .spec import ModelSpec
from .variables import Variable, number_variables

#: MIME type of the Tx/Rx data variables (FMI-LS-BUS 1.0, "MIME Types").
CAN_MIME_TYPE = 'application/org.fmi-standard.fmi-ls-bus.can; version="1.0.0"'
#: Name of the bus terminal and prefix of its variables.
TERMINAL = "CAN"
#: maxSize of the data variables, bytes (config.h PL_RX_DATA_MAX_SIZE, PL_TX_DATA_MAX_SIZE: the buffers'
#: sizes in fmu/c/plant_can/bus_state.h).
RX_CAPACITY, TX_CAPACITY = 8192, 4096
#: CiA 402 defaults of the drive EDS (hil/eds/drive402.eds) the FMU's drives use: torque slope 0x6087
#: (per mille/s, the quick stop ramp) and the SYNC loss time (s) of the emulator's nodes.
TORQUE_SLOPE, SYNC_TIMEOUT = 10000, 0.1

PLANT_CAN_SOURCES = ("model.c", "canopen_nodes.c", "lsbus_can.c", "plant_can.h", "bus_state.h")
PLANT_SOURCES = ("plant/plant.c", "plant/plant.h", "plant/plant_fmu.c", "plant/plant_fmu.h")

PLANT_CAN_DESCRIPTION = (
    "The plant of '{name}' behind its CAN bus (FMI-LS-BUS network abstraction, terminal CAN): CiA 402 drives "
    "1-4 (fl, rl, fr, rr; RPDO1 0x200+id controlword + target torque, TPDO1 0x180+id statusword + position, "
    "TPDO2 0x280+id velocity + torque actual, cyclic synchronous torque) and CiA 406 steering encoders 5, 6 "
    "(TPDO1 0x180+id position value), NMT and SYNC, lock-step: at a SYNC the drives latch their torque, the "
    "sensors are sampled and the TPDOs sent; the torque is held until the next SYNC. " + PLANT_DESCRIPTION)


def plant_can_variables(p: dict[str, float], geometry, i_G: float, eps: float = DEFAULT_EPS,
                        std: dict[str, float] | None = None) -> list[Variable]:
    """The plant's variables (:func:`qomni.fmu.plant_spec.plant_variables`) with the torques as outputs,
    the drive data as parameters and the bus terminal's four variables (order = value references):

    * parameters ``rated_torque`` (N m, 0x6076), ``cycle_time`` (s, 0x1006), ``sync_timeout`` (s, 0 = no
      SYNC-loss supervision), ``max_torque`` (per mille of rated, 0x6072), ``torque_slope`` (per mille/s,
      0x6087), ``encoder_increments``, ``steering_sensor_bits``; start values from the data sheet
      (:func:`with_datasheet`);
    * outputs ``motor_torque.<wheel>`` (N m motor side, the torque each drive applies);
    * ``CAN.Rx_Data`` (Binary input, clocked by ``CAN.Rx_Clock``, triggered input Clock), ``CAN.Tx_Data``
      (Binary output, clocked by ``CAN.Tx_Clock``, triggered output Clock).
    """
    base = [replace(v, vr=-1, index=-1) for v in plant_variables(p, geometry, i_G, eps, std)]
    out: list[Variable] = []
    for v in base:
        if v.causality == "input":
            v = replace(v, causality="output", variability="continuous", start=None, min=None, max=None,
                        description=f"torque applied by the drive of wheel {v.name.split('.')[-1]}, motor side "
                                    "of the gear (per mille of rated_torque from the last SYNC on)")
        out.append(v)
    at = next(j for j, v in enumerate(out) if v.name == "x0")
    drive = [
        Variable("rated_torque", "Float64", "parameter", "fixed", "motor rated torque (0x6076 / 1000)",
                 start=1.0, unit="N.m", group="RATED_TORQUE"),
        Variable("cycle_time", "Float64", "parameter", "fixed", "communication cycle period 0x1006 (the "
                 "quick stop ramp's period)", start=0.002, unit="s", group="CYCLE_TIME"),
        Variable("sync_timeout", "Float64", "parameter", "fixed", "SYNC loss time: no SYNC for longer in "
                 "OPERATIONAL -> EMCY 0x8100 and the drives fault (0x6007 = 1); 0 = no supervision",
                 start=SYNC_TIMEOUT, unit="s", group="SYNC_TIMEOUT"),
        Variable("max_torque", "Int32", "parameter", "fixed", "max torque 0x6072, per mille of the rated torque",
                 start=1000, group="MAX_TORQUE"),
        Variable("torque_slope", "Int32", "parameter", "fixed", "torque slope 0x6087, per mille per second "
                 "(quick stop ramp)", start=TORQUE_SLOPE),
        Variable("encoder_increments", "Int32", "parameter", "fixed", "motor encoder increments per motor "
                 "revolution (0x6064)", start=1),
        Variable("steering_sensor_bits", "Int32", "parameter", "fixed", "resolution of the absolute steering "
                 "sensors (0x6004 counts 2^bits per revolution)", start=1),
    ]
    out[at:at] = drive
    rx_clock, tx_clock = len(out), len(out) + 2       # value references = list positions (number_variables)
    bus = [
        Variable(f"{TERMINAL}.Rx_Clock", "Clock", "input", "discrete",
                 "input clock of CAN.Rx_Data: activated by the importer when operations arrive",
                 group="RX_CLOCK", attributes=(("intervalVariability", "triggered"),)),
        Variable(f"{TERMINAL}.Rx_Data", "Binary", "input", "discrete",
                 "bus operations received (FMI-LS-BUS CAN: CAN Transmit of the master's frames)", start="",
                 group="RX_DATA", attributes=(("mimeType", CAN_MIME_TYPE), ("maxSize", str(RX_CAPACITY)),
                                              ("clocks", str(rx_clock)))),
        Variable(f"{TERMINAL}.Tx_Clock", "Clock", "output", "discrete",
                 "output clock of CAN.Tx_Data: active while transmitted frames wait for the importer",
                 group="TX_CLOCK", attributes=(("intervalVariability", "triggered"),)),
        Variable(f"{TERMINAL}.Tx_Data", "Binary", "output", "discrete",
                 "bus operations sent (FMI-LS-BUS CAN: CAN Transmit of the nodes' frames, Format Error)",
                 group="TX_DATA", attributes=(("mimeType", CAN_MIME_TYPE), ("maxSize", str(TX_CAPACITY)),
                                              ("clocks", str(tx_clock)))),
    ]
    return number_variables(out + bus)


def with_datasheet(variables: list[Variable], datasheet) -> list[Variable]:
    """The drive parameters' start values from the data sheet's drive section (rated and max torque in N m ->
    0x6072 per mille, increments, sensor bits, T_s)."""
    d = datasheet.drive
    start = {"rated_torque": float(d.rated_torque), "cycle_time": float(d.cycle_time),
             "max_torque": int(round(1000.0 * d.max_torque / d.rated_torque)),
             "encoder_increments": int(d.encoder_increments), "steering_sensor_bits": int(d.steering_sensor_bits)}
    return [replace(v, start=start[v.name]) if v.name in start else v for v in variables]


def terminals_and_icons(variables: list[Variable]) -> bytes:
    """``terminalsAndIcons/terminalsAndIcons.xml`` (FMI 3.0 section 2.4.9; FMI-LS-BUS "Bus Terminal")."""
    from xml.etree import ElementTree as ET

    from .description import xml_bytes
    root = ET.Element("fmiTerminalsAndIcons", fmiVersion="3.0")
    terminals = ET.SubElement(root, "Terminals")
    terminal = ET.SubElement(terminals, "Terminal", terminalKind="org.fmi-ls-bus.network-terminal", name=TERMINAL,
                             matchingRule="org.fmi-ls-bus.transceiver",
                             description="the vehicle's CANopen bus (drives 1-4, steering encoders 5-6)")
    for member in ("Tx_Data", "Tx_Clock", "Rx_Data", "Rx_Clock"):
        ET.SubElement(terminal, "TerminalMemberVariable", variableKind="signal",
                      variableName=f"{TERMINAL}.{member}", memberName=member)
    return xml_bytes(root)


def ls_bus_manifest(variables: list[Variable]) -> bytes:
    """``extra/org.fmi-standard.fmi-ls-bus/fmi-ls-manifest.xml`` (FMI 3.0 section 2.5.1.4, layered standard
    manifest; this FMU is a Network FMU, not a Bus Simulation)."""
    from xml.etree import ElementTree as ET

    from .description import xml_bytes
    root = ET.Element("fmiLayeredStandardManifest", {
        "xmlns:fmi-ls": "http://fmi-standard.org/fmi-ls-manifest",
        "fmi-ls:fmi-ls-name": "org.fmi-standard.fmi-ls-bus", "fmi-ls:fmi-ls-version": "1.0.0",
        "fmi-ls:fmi-ls-description": "Layered Standard for the simulation of bus communication (network "
                                     "abstraction, CAN)",
        "isBusSimulationFMU": "false"})
    return xml_bytes(root)


def extra_files(variables: list[Variable]) -> dict[str, bytes]:
    return {"terminalsAndIcons/terminalsAndIcons.xml": terminals_and_icons(variables),
            "extra/org.fmi-standard.fmi-ls-bus/fmi-ls-manifest.xml": ls_bus_manifest(variables)}


PLANT_CAN = ModelSpec(
    kind="plant-can", default_identifier="qomni_plant_can", model_dir="plant_can", model_sources=PLANT_CAN_SOURCES,
    generate=codegen.generate_plant_c, variables=plant_can_variables, dependencies=(), config_prefix="PL",
    n_states=PLANT_N_STATES, description=PLANT_CAN_DESCRIPTION,
    summary="plant behind its CAN bus (FMI-LS-BUS CAN terminal, CiA 402/406 PDO path)",
    shared_sources=PLANT_SOURCES, bus=True, fmi_versions=(3,), with_datasheet=with_datasheet,
    extra_files=extra_files)

__all__ = ["CAN_MIME_TYPE", "PLANT_CAN", "TERMINAL", "plant_can_variables", "with_datasheet"]
