"""Virtual motors described by a motor file: `bench data --motor FILE` simulates the file's `virtual_plant`.

The built-in 200 kW machine (bench.drive.generate) is hard-wired; this package turns any motor file with a
`virtual_plant` table and an electrical loss model into a set of measurement files of the kind a user brings:
the motor's own column names and units, no time column, a sample period of its own. The examples/motor-ipm
motor is one.

Modules, each building on the ones before it:
- machine: the dq machine (Machine, TrueLosses, DqModel: torque -> currents -> voltages)
- profiles: the measurement runs (Profile, Phase) and the torque and speed of their non-cycle phases
- phases: reading a profile's phases from the motor file, one reader per phase kind
- plants: the kinds of thermal plant (registry PLANT_KINDS: lptn4, distributed) and their interface
- simulation: VirtualPlant (drive, stand, true losses, sensors; the kind's thermal truth) and VirtualRun
- schema: the `virtual_plant` table's schema, read and checked into a VirtualPlant (virtual_plant())
- output: the CSV files and their index, profiles.json (generate_profiles())
"""

from bench.drive.virtual.errors import VirtualPlantError
from bench.drive.virtual.machine import DqModel, Machine, TrueLosses
from bench.drive.virtual.output import GENERATOR_VERSION, INDEX_NAME, generate_profiles
from bench.drive.virtual.phases import PHASE_KINDS
from bench.drive.virtual.profiles import ROLES, Phase, Profile
from bench.drive.virtual.schema import SCHEMA_VERSION, load_virtual_plant, virtual_plant
from bench.drive.virtual.simulation import SIGNALS, OutputColumn, VirtualPlant, VirtualRun

__all__ = ["GENERATOR_VERSION", "INDEX_NAME", "PHASE_KINDS", "ROLES", "SCHEMA_VERSION", "SIGNALS", "DqModel",
           "Machine", "OutputColumn", "Phase", "Profile", "TrueLosses", "VirtualPlant", "VirtualPlantError",
           "VirtualRun", "generate_profiles", "load_virtual_plant", "virtual_plant"]
