"""The observer as the target runs it: a discrete Kalman filter on the model's linear block, in float32, bit for bit
what the firmware's generated C does.

- `filter`: the filter step (`Float32Observer`): model step, time update, each measurement's update, checkpoints;
- `transition`: the time update's F (`Transition`); `layout`: the extra states (lags, bias) and each measurement's
  row h (`AugmentedLayout`); `consider`: the states an update holds (`ConsiderStates`); `gate`: the innovation gate
  (`InnovationGate`);
- `forms`: the covariance forms (`OBSERVER_FORMS`: conventional, joseph, ud, steady), `ud` the UD form;
- `coordinates`: the node coordinates the filter runs in; `ud_structure`: the UD form's structural zeros and
  schedules;
- `section`: the artifact's observer section as the target reads it; `measurements/`: one module per measurement
  kind (`MEASUREMENT_KINDS`);
- `offline`: the filter over a whole dataset (`run_observer_offline`); `node`: the node's glue (its CAN channels,
  slots and signals).
"""

from target_sim.observer.filter import Float32Observer
from target_sim.observer.forms import OBSERVER_FORMS
from target_sim.observer.offline import ObserverRun, run_observer_offline
from target_sim.observer.section import (
    ObserverError,
    has_observer,
    load_measurements,
    measurement_entries,
    state_count,
)

__all__ = ["OBSERVER_FORMS", "Float32Observer", "ObserverError", "ObserverRun", "has_observer", "load_measurements",
           "measurement_entries", "run_observer_offline", "state_count"]
