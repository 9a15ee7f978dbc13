"""Drive data: the FTP-75/WLTC3 test sequence, a virtual 200 kW out-runner PMSM, and its datasets.

Modules (imported on demand; this package imports nothing heavy):
- cycles: the shipped FTP-75 and WLTC class 3b speed traces, verified at load
- vehicle: vehicle and driveline, speed trace -> motor torque and speed
- sequence: the 7274 s test sequence (preheat, FTP-75, preheat, WLTC3) with its phases
- motor: MotorSpec (the single source of truth for the machine) and the nominal LossMaps
- stand: coolant inlet and test-cell temperature of the test stand (built-in and motor-file stands alike)
- plant: the thermal truth (parameter-varying LPTN, true losses), exact-step and ODE integration
- sensors: 5 Hz instruments with noise and quantization
- generate: one measurement run for one coolant set point, and the default datasets written from them
- seed: the datasets' default noise seed (standard library only: `bench data --help` names it)
- dataset: the file format: schema, CSV + JSON sidecar writer, loader with column mapping, DatasetError
- baseline: the LTI LPTN with nominal maps, the gap the Hammerstein model has to close
- plots: PNGs of a dataset (matplotlib, imported lazily)
- virtual: virtual motors described by a motor file's virtual_plant table (`bench data --motor`), a package
"""
