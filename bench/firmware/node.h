/* node.h - the bench target's CAN node as firmware: the behaviour target_sim/node.py states, in C99.
 *
 * The node around the model (fw_model.h): frame validation (id, DLC, the E2E profile-2 CRC8 and alive counter,
 * signal ranges), the state machine IDLE/READY/RUNNING/STOPPED/FAULT, the data-row sequence rules, the interval
 * means, the model steps and their timing, RxErrors counters, heartbeat and TargetInfo, StateCheckpoint and
 * RestoreState, clamping of the transmitted temperatures and the fault bits. Bit packing comes from the DBC through
 * `cantools generate_c_source` (thermal_bench.h/.c, generated at build time); the facts of the contract (ids,
 * enums, E2E data ids, scalings, heartbeat period) from fw_node_config.h, which `bench firmware export` writes
 * from the DBC and the project's contract module, so none of them is typed in here.
 *
 * A data row is the row messages of the model's loss model, in order and of one Step (fw_node_config.h's
 * NODE_ROW_*, from dbc.contract.row_messages): DriveInputs + DriveTemps for loss maps, and DriveCurrents (DBC 1.4.0,
 * the d/q currents) after them for an electrical loss model, whose model then accumulates 6 values per row. A
 * loss-map model's node validates DriveCurrents like every frame and otherwise ignores it, as the Python node does.
 *
 * No heap, no libc (the two memory functions the generated packers call are defined in node.c), no recursion,
 * no double. One node instance, in static RAM.
 *
 * Use (an MCU's main loop; the bench's shell, target_sim.firmware.node_engine, does the same in the emulator):
 *   node_init(now_ms);                               once: IDLE, queues TargetInfo, Status, RxErrors
 *   per received frame: copy it into node_rx (the receive mailbox) and call node_on_frame(id, dlc, node_rx.data),
 *   or node_on_xcp(dlc, node_rx.data) for the XCP command id
 *   every millisecond or so: node_on_tick(now_ms)    queues Status + RxErrors when a heartbeat period is over
 *   after each call: send node_out.tx[0 .. node_out.tx_count-1] in order; read node_out.events (the journal)
 * Every entry point starts by emptying node_out: what a call queued must be sent before the next call.
 *
 * Queues are bounded: NODE_TX_CAPACITY frames (40; a model with an observer: its checkpoint's elements more, since
 * its ObserverCheckpoint follows a StateCheckpoint in the same call) and NODE_EVENT_CAPACITY journal records per
 * call. A frame or record that does not fit is dropped and counted (node_out.tx_dropped, node_out.events_dropped:
 * totals since node_init); the temperature replies are queued first, so only timing, observer and checkpoint frames
 * of a row that arrives after several model steps of lost rows (~8 open loop, ~4 with an observer and its
 * checkpoint) can be dropped (the Python reference node has no such bound: the one place where the two may
 * differ).
 *
 * Frame ids: the 11-bit id, with NODE_ID_EXTENDED / NODE_ID_REMOTE / NODE_ID_ERROR / NODE_ID_FD or-ed in for such
 * frames (all rejected as unknown ids, as the contract says).
 *
 * Timing: the model step is timed with the Cortex-M's DWT cycle counter (DWT_CYCCNT, enabled by node_init); the
 * cycles go out in Timing4 and, at NODE_CLOCK_HZ, in Timing1's StepTimeMeasured. Timing2/Timing3 carry the C28x
 * estimate of the bench's cost model (target_sim.costs), constants of fw_node_config.h.
 */
#ifndef NODE_H
#define NODE_H

#include <stdint.h>

#include "fw_node_config.h" /* NODE_TX_CAPACITY, NODE_EVENT_CAPACITY: target_sim.firmware.node_protocol's */

#define NODE_ID_EXTENDED 0x80000000u
#define NODE_ID_REMOTE 0x40000000u
#define NODE_ID_ERROR 0x20000000u
#define NODE_ID_FD 0x10000000u

/* One CAN frame (classic, 8 data bytes at most). */
struct node_frame {
    uint32_t id;
    uint32_t dlc;
    uint8_t data[8];
};

/* One journal record: a rejected frame or a sequence error (target_sim.node's detection journal), or the reason
 * of the last error. kind: NODE_KIND_*; code: NODE_WHY_* (what exactly, for the sentence the shell writes);
 * a, b: the numbers that sentence names (steps, counters, CRCs, a signal's index); the frame judged. */
struct node_event {
    uint8_t kind;
    uint8_t code;
    uint8_t dlc;
    uint8_t reserved;
    uint32_t id;
    uint8_t data[8];
    int32_t a;
    int32_t b;
};

/* What the last call produced, and the node's state as the shell needs it after every call. */
struct node_output {
    uint32_t tx_count;
    uint32_t event_count;
    uint32_t state;             /* Status.State */
    uint32_t faults;            /* Status.FaultBits */
    uint32_t answered_again;    /* the last frame was a repeated row, answered again */
    uint32_t tx_dropped;        /* totals since node_init */
    uint32_t events_dropped;
    uint32_t last_step_cycles;  /* DWT cycles of the last model step */
    uint32_t step_cycles;       /* DWT cycles of the model steps of the last call (0: it stepped nothing) */
    uint32_t next_beat_ms;      /* when node_on_tick sends the next heartbeat */
    struct node_frame tx[NODE_TX_CAPACITY];
    struct node_event events[NODE_EVENT_CAPACITY];
};

/* Counters for the bench's statistics (target_sim.node.TargetNode.stats). */
struct node_counters {
    uint32_t errors[6];         /* per RX_ERROR_KINDS, not saturated (RxErrors saturates at 255) */
    uint32_t frames_received;
    uint32_t rows_used;
    uint32_t repeats;
    uint32_t model_steps;
    uint32_t overruns;
    struct node_event last_error;   /* kind 0: none yet */
};

/* The receive mailbox: the shell (or a CAN driver) writes a received frame here. */
extern struct node_frame node_rx;
extern struct node_output node_out;
extern struct node_counters node_counters;

/* Power-on: IDLE with the model loaded, counters zero; queues TargetInfo, Status and RxErrors. */
void node_init(uint32_t now_ms);

/* Validate one received frame and act on it; the replies are in node_out.tx. */
void node_on_frame(uint32_t id, uint32_t dlc, const uint8_t *data);

/* The heartbeat: Status and RxErrors once per NODE_HEARTBEAT_MS (catching up at most one period). */
void node_on_tick(uint32_t now_ms);

/* An internal fault the node's host detected (the core faulted, a watchdog): INTERNAL, state FAULT, Status. */
void node_internal_fault(uint32_t code);

/* One XCP command (a frame of the XCP command id, dbc/xcp.toml: the shell routes it here, as a CAN controller's
 * filter routes it to its own FIFO; never a frame of the contract, never a model step): its reply in node_out.tx. */
void node_on_xcp(uint32_t dlc, const uint8_t *data);

/* The XCP slave (xcp.c): a command's reply into node_out.tx, and an event channel's DAQ packets (after each model
 * step, on the heartbeat tick), sent at the end of the call. */
void xcp_command(uint32_t dlc, const uint8_t *data);
void xcp_event(uint32_t event);

/* The raw value a temperature (deg C) goes out with: clamped to the DBC range, round half to even of
 * (value - offset) / scale computed exactly (what the Python codec's double arithmetic gives); exposed for tests. */
uint32_t node_temperature_raw(float value);

#endif /* NODE_H */
