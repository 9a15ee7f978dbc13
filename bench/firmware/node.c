/* node.c - the bench target's CAN node as firmware (see node.h): target_sim/node.py's rules, in C99.
 *
 * Each function names the method of target_sim.node.TargetNode it mirrors; the Python node stays the reference
 * implementation and the bench's conformance suite feeds both the same frames and compares the replies byte for
 * byte. Arithmetic that must give the Python codec's bits is done exactly in integers (node_temperature_raw) or in
 * float32 operations proven equal to it (the NODE_DECODE_* macros of fw_node_config.h; the tests check every raw
 * value).
 */
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "fw_model.h"
#include "fw_node_config.h"
#include "node.h"
/* The generated packers in this translation unit, so the compiler inlines them into the node: fewer calls, less
 * code, fewer basic blocks for the emulator to hook (the build compiles thermal_bench.c only through here). */
#include "thermal_bench.c"

/* A data row is what the model accumulates: the node's row (fw_node_config.h) and the model's inputs (fw_model.h)
 * are generated from one artifact and must agree (a negative array size stops the build otherwise). */
typedef char node_row_is_the_model_input[(NODE_ROW_WIDTH == FW_INPUTS) ? 1 : -1];

#ifdef FW_OBSERVER
/* A model with an observer (fw_model.h's fw_obs_*, TargetNode with a NodeObserver): the row's sample carries the
 * observer's raw channels after the drive values (NODE_OBS_RAW: the VALID values of the measurement frames of the
 * row's Step, NaN otherwise, and the row's own values the flux linkage reads), the model steps through the filter
 * (a measurement without a reading is not used; none: the step predicts only), every model step is answered after
 * its timing frames with Uncertainty1, Uncertainty2 and Innovations, and each StateCheckpoint is followed by the
 * filter's ObserverCheckpoint; a RESTORE with every RestoreObserver element of its Step continues the filter from
 * them, else starts its covariance at P0. */
typedef char node_observer_is_the_model_observer[(NODE_OBSERVER == FW_OBSERVER && NODE_OBS_CHANNELS == FW_OBS_CHANNELS
                                                  && NODE_OBS_MEASUREMENTS == FW_OBS_MEASUREMENTS
                                                  && NODE_OBS_CHECKPOINT_SIZE == FW_OBS_CHECKPOINT_SIZE) ? 1 : -1];
#define NODE_SAMPLE_WIDTH (NODE_ROW_WIDTH + NODE_OBS_CHANNELS)
#define OBSERVER_FRAMES 3u
#define REPORT_WIDTH (4u + NODE_OBS_MEASUREMENTS)
/* the arrays of the checkpoint's elements: a steady-state gain without lag or bias has none (no zero-size array) */
#define OBS_CHECKPOINT_SLOTS (NODE_OBS_CHECKPOINT_SIZE > 0u ? NODE_OBS_CHECKPOINT_SIZE : 1u)
#define MODEL_STEP fw_obs_step
#define MODEL_RESET fw_obs_reset
#define MODEL_RESTORE fw_obs_restore
#define NO_READING __builtin_nanf("")
#else
#define NODE_SAMPLE_WIDTH NODE_ROW_WIDTH
#define OBSERVER_FRAMES 0u
#define MODEL_STEP fw_step
#define MODEL_RESET fw_reset
#define MODEL_RESTORE fw_restore
#endif

/* node_out.tx holds the call's replies, then the XCP slave's DAQ packets (xcp.c): the last XCP_DAQ_QUEUE frames are
 * theirs */
#define NODE_REPLY_CAPACITY (NODE_TX_CAPACITY - XCP_DAQ_QUEUE)

struct node_frame node_rx;
struct node_output node_out;
struct node_counters node_counters;

/* The DWT cycle counter (ARMv7-M debug unit): the model step is timed with it, as on the silicon. */
#define DEMCR (*(volatile uint32_t *)0xE000EDFCu)
#define DWT_CTRL (*(volatile uint32_t *)0xE0001000u)
#define DWT_CYCCNT (*(volatile uint32_t *)0xE0001004u)

#ifdef NODE_WITH_ISR
/* The timing image (bench run --engine firmware --isr-rate, bench firmware timing): the motor-control interrupt
 * (foc_isr.c) preempts the node; each model step's response time and the interrupt's CPU load go out in Timing5.
 * node_rx_stamp is the CAN controller's time stamp of the frame in node_rx (the DWT cycle count at its reception,
 * as an FDCAN's RX time stamp gives it): a step's response time runs from the reception of the frame that
 * completed its interval to the DWT count after fw_step returned (the interrupts in between included). */
#include "foc_isr.h"
#define TIMING_FRAMES 5u
volatile uint32_t node_rx_stamp;
static uint32_t step_ended;                       /* DWT_CYCCNT after the last fw_step */
static uint32_t ticks_since, busy_since;          /* IsrLoad's window: foc_ticks and foc_busy_cycles then */
static struct {
    uint32_t response;                            /* DWT cycles, reception -> result */
    uint32_t load;                                /* IsrLoad's raw value (0.01 %) */
} response_of[NODE_REPLY_CAPACITY / TIMING_FRAMES];
#else
#define TIMING_FRAMES 4u
#endif

/* The messages the node receives, one index each: NODE_RX_LIST of fw_node_config.h (X(NAME, name, frame id) for
 * every message the DBC gives receiver TARGET, by frame id), with their frame and E2E data ids. */
#define RX_INDEX(NAME, name, id) RX_##NAME,
enum rx_message { NODE_RX_LIST(RX_INDEX) RX_COUNT };
#define RX_ID(NAME, name, id) id,
static const uint32_t rx_ids[RX_COUNT] = {NODE_RX_LIST(RX_ID)};
#define RX_DATA_ID(NAME, name, id) NODE_DATA_ID_##NAME,
static const uint8_t rx_data_ids[RX_COUNT] = {NODE_RX_LIST(RX_DATA_ID)};

/* ---- the node's state (TargetNode's attributes) ---- */
static uint8_t state;
static uint8_t faults;
static uint8_t counter_known[RX_COUNT];          /* FrameValidator._last_counter */
static uint8_t counter_last[RX_COUNT];
static uint8_t tx_counter[NODE_TX_MESSAGES];      /* FrameCodec._next_counter, by NODE_TX_* index */
static const struct node_frame *rx_frame;         /* the frame being handled, for the journal */

static struct {                                   /* RESET's messages (NODE_RESET_LIST): _reset_frames */
    uint8_t have;
    uint16_t step;
    uint16_t raw[NODE_RESET_WIDTH];
} reset_frames[NODE_RESET_MESSAGES];
static struct {                                   /* RestoreState by element: _restore_frames */
    uint8_t have;
    uint16_t step;
    float value;
} restore_frames[NODE_STATE_SIZE];
static struct {                                   /* _pending: the row being received */
    uint8_t count;                                /* its frames so far, in row order (NODE_ROW_INDEX_*) */
    uint16_t step;                                /* the Step of its first frame */
    float sample[NODE_SAMPLE_WIDTH];              /* their values, decoded into their places of the row */
} pending;
#ifdef FW_OBSERVER
static struct {                                   /* TargetNode._measurement: the last frame of each message */
    uint8_t have;
    uint8_t order;                                /* when it came first since the last row (dict order) */
    uint16_t step;
    float channels[NODE_HOST_CHANNELS];           /* its channels' VALID values, NaN otherwise and elsewhere */
} measurement[NODE_MEASUREMENT_MESSAGES];
static uint8_t measurement_arrivals;
static struct {                                   /* TargetNode._observer_restore: RestoreObserver by Index */
    uint8_t have;
    uint16_t step_low;
    float value;
} restore_observer[OBS_CHECKPOINT_SLOTS];
static float report_of[NODE_REPLY_CAPACITY / (4u + OBSERVER_FRAMES)][REPORT_WIDTH];   /* per timed step */
static unsigned char gate_of[NODE_REPLY_CAPACITY / (4u + OBSERVER_FRAMES)][NODE_OBS_MEASUREMENTS];   /* fw_obs_gate */
#endif

static uint8_t running_rows;                      /* next_row is not None */
static uint32_t next_row;
static uint8_t have_reply_row;                    /* last_reply_row is not None */
static uint16_t last_reply_step;
static uint8_t have_last_inputs;                  /* RowAccumulator.last_inputs */
static float last_inputs[NODE_SAMPLE_WIDTH];
static float estimate[NODE_STATE_SIZE];
static uint32_t next_beat_ms;

/* ------------------------------------------------------------------------------------------------ no libc */
/* The generated packers call these two; -ffreestanding leaves them to us. */
void *memset(void *s, int c, size_t n)
{
    uint8_t *p = (uint8_t *)s;
    while (n-- > 0u) *p++ = (uint8_t)c;
    return s;
}

void *memcpy(void *restrict d, const void *restrict s, size_t n)
{
    uint8_t *to = (uint8_t *)d;
    const uint8_t *from = (const uint8_t *)s;
    while (n-- > 0u) *to++ = *from++;
    return d;
}

/* ------------------------------------------------------------------------------------------------ E2E */
/* dbc.codec.profile2_crc: AUTOSAR CRC8H2F (poly 0x2F, init and xor-out 0xFF) over bytes 1..7 and the data id,
 * from the table dbc.codec uses (fw_node_config.h): one look-up per byte. */
static const uint8_t crc8h2f_table[256] = {NODE_CRC8H2F_TABLE};

static uint8_t profile2_crc(const uint8_t data[8], uint8_t data_id)
{
    uint8_t crc = 0xFFu;
    int i;
    for (i = 1; i < 8; i++) crc = crc8h2f_table[crc ^ data[i]];
    return (uint8_t)(crc8h2f_table[crc ^ data_id] ^ 0xFFu);
}

/* ------------------------------------------------------------------------------------------------ queues */
static struct node_frame *tx_slot(void)
{
    if (node_out.tx_count >= NODE_REPLY_CAPACITY) {
        node_out.tx_dropped++;
        return NULL;
    }
    return &node_out.tx[node_out.tx_count++];
}

/* FrameCodec.encode's tail: alive counter into byte 1's low nibble (already packed), CRC into byte 0. */
static void tx_finish(struct node_frame *frame, uint32_t id, unsigned int tx_index, uint8_t data_id)
{
    frame->id = id;
    frame->dlc = 8u;
    frame->data[0] = profile2_crc(frame->data, data_id);
    tx_counter[tx_index] = (uint8_t)((tx_counter[tx_index] + 1u) % NODE_COUNTER_MODULO);
}

static void record(uint8_t kind, uint8_t code, int32_t a, int32_t b)
{
    struct node_event *event = &node_counters.last_error;
    event->kind = kind;
    event->code = code;
    event->a = a;
    event->b = b;
    event->id = rx_frame != NULL ? rx_frame->id : 0u;
    event->dlc = rx_frame != NULL ? (uint8_t)rx_frame->dlc : 0u;
    memcpy(event->data, rx_frame != NULL ? rx_frame->data : node_rx.data, sizeof event->data);
    if (kind > NODE_KIND_SEQUENCE || rx_frame == NULL) return;      /* the journal: rejected frames, sequence */
    if (node_out.event_count >= NODE_EVENT_CAPACITY) {
        node_out.events_dropped++;
        return;
    }
    node_out.events[node_out.event_count++] = *event;
}

/* The XCP slave (xcp.c): its replies and DAQ packets go through tx_slot and node_out. */
#include "xcp.c"

/* ------------------------------------------------------------------------------------------------ sending */
static uint8_t saturate8(uint32_t value)
{
    return (uint8_t)(value > 255u ? 255u : value);
}

/* TargetNode.status_frames */
static void send_status(void)
{
    struct thermal_bench_status_t m;
    struct node_frame *frame = tx_slot();
    if (frame == NULL) return;
    thermal_bench_status_init(&m);
    m.status_counter = tx_counter[NODE_TX_STATUS];
    m.state = state;
    m.fault_bits = faults;
    m.model_id = FW_MODEL_ID;
    m.dbc_version_major = NODE_DBC_VERSION_MAJOR;
    m.dbc_version_minor = NODE_DBC_VERSION_MINOR;
    (void)thermal_bench_status_pack(frame->data, &m, 8u);
    tx_finish(frame, THERMAL_BENCH_STATUS_FRAME_ID, NODE_TX_STATUS, NODE_DATA_ID_STATUS);
}

/* TargetNode.rx_error_frames */
static void send_rx_errors(void)
{
    struct thermal_bench_rx_errors_t m;
    struct node_frame *frame = tx_slot();
    const uint32_t *e = node_counters.errors;
    if (frame == NULL) return;
    thermal_bench_rx_errors_init(&m);
    m.rx_errors_counter = tx_counter[NODE_TX_RX_ERRORS];
    NODE_FILL_RX_ERRORS(m, e);
    (void)thermal_bench_rx_errors_pack(frame->data, &m, 8u);
    tx_finish(frame, THERMAL_BENCH_RX_ERRORS_FRAME_ID, NODE_TX_RX_ERRORS, NODE_DATA_ID_RX_ERRORS);
}

/* The image's own size, from the linker script (what memory_from_elf reads from the sections). */
extern const char _fw_flash_bytes[], _fw_ram_bytes[];

static uint32_t clamp_u32(uint32_t value, uint32_t maximum)
{
    return value > maximum ? maximum : value;
}

/* TargetNode.target_info_frames: flash and RAM of this very image. */
static void send_target_info(void)
{
    struct thermal_bench_target_info_t m;
    struct node_frame *frame = tx_slot();
    if (frame == NULL) return;
    thermal_bench_target_info_init(&m);
    m.target_info_counter = tx_counter[NODE_TX_TARGET_INFO];
    m.model_kind = NODE_MODEL_KIND;
    m.realization = NODE_REALIZATION;
    m.model_dt = NODE_MODEL_DT_RAW;
    m.flash_bytes = clamp_u32((uint32_t)(uintptr_t)_fw_flash_bytes, NODE_FLASH_BYTES_MAX);
    m.ram_bytes = (uint16_t)clamp_u32((uint32_t)(uintptr_t)_fw_ram_bytes, NODE_RAM_BYTES_MAX);
    (void)thermal_bench_target_info_pack(frame->data, &m, 8u);
    tx_finish(frame, THERMAL_BENCH_TARGET_INFO_FRAME_ID, NODE_TX_TARGET_INFO, NODE_DATA_ID_TARGET_INFO);
}

/* value = sign * M * 2^E exactly (M < 2^24); raw = round_half_even(value * inv + offset_raw), inv = 1/scale and
 * offset_raw = -offset/scale integers: exact in 64-bit integers for the DBC range (|E| <= 40 there). */
static uint32_t exact_raw(float value, int64_t inv, int64_t offset_raw)
{
    union {
        float f;
        uint32_t u;
    } bits;
    uint32_t exponent, mantissa;
    int32_t shift;
    int64_t numerator, quotient, remainder, half;
    bits.f = value;
    exponent = (bits.u >> 23) & 0xFFu;
    mantissa = bits.u & 0x7FFFFFu;
    if (exponent < 127u - NODE_TEMP_TINY_EXPONENT) return (uint32_t)offset_raw;  /* |v| * inv < 1/64: no effect */
    mantissa |= 0x800000u;
    shift = 150 - (int32_t)exponent;                                           /* value = M * 2^-shift */
    numerator = (int64_t)mantissa * inv;
    if (bits.u & 0x80000000u) numerator = -numerator;
    if (shift <= 0) return (uint32_t)(numerator * ((int64_t)1 << -shift) + offset_raw);
    numerator += offset_raw << shift;                    /* the floor below rounds a negative one the same way */
    quotient = numerator >> shift;
    remainder = numerator - (quotient << shift);
    half = (int64_t)1 << (shift - 1);
    if (remainder > half || (remainder == half && (quotient & 1))) quotient++;
    return (uint32_t)quotient;
}

uint32_t node_temperature_raw(float value)
{
    return exact_raw(value, NODE_TEMP_INV_SCALE, NODE_TEMP_OFFSET_RAW);
}

static int is_finite(float value)
{
    union {
        float f;
        uint32_t u;
    } bits;
    bits.f = value;
    return ((bits.u >> 23) & 0xFFu) != 0xFFu;
}

/* TargetNode._temperature_frames: clamp (SATURATED, NONFINITE), then Temperatures1 and Temperatures2. */
static void send_temperatures(uint16_t step)
{
    uint32_t raw[NODE_STATE_SIZE];
    unsigned int i;
    for (i = 0; i < NODE_STATE_SIZE; i++) {
        float value = estimate[i];
        if (!is_finite(value)) {
            faults |= NODE_FAULT_NONFINITE | NODE_FAULT_SATURATED;
            value = (value > 0.0f || value != value) ? NODE_TEMP_MAX : NODE_TEMP_MIN;
        } else if (value < NODE_TEMP_MIN || value > NODE_TEMP_MAX) {
            faults |= NODE_FAULT_SATURATED;
            value = value < NODE_TEMP_MIN ? NODE_TEMP_MIN : NODE_TEMP_MAX;
        }
        raw[i] = node_temperature_raw(value);
    }
    {
        struct thermal_bench_temperatures1_t m;
        struct node_frame *frame = tx_slot();
        if (frame != NULL) {
            thermal_bench_temperatures1_init(&m);
            m.temperatures1_counter = tx_counter[NODE_TX_TEMPERATURES1];
            m.temperatures1_step = step;
            NODE_FILL_TEMPERATURES1(m, raw);
            (void)thermal_bench_temperatures1_pack(frame->data, &m, 8u);
            tx_finish(frame, THERMAL_BENCH_TEMPERATURES1_FRAME_ID, NODE_TX_TEMPERATURES1,
                      NODE_DATA_ID_TEMPERATURES1);
        }
    }
    {
        struct thermal_bench_temperatures2_t m;
        struct node_frame *frame = tx_slot();
        if (frame != NULL) {
            thermal_bench_temperatures2_init(&m);
            m.temperatures2_counter = tx_counter[NODE_TX_TEMPERATURES2];
            m.temperatures2_step = step;
            NODE_FILL_TEMPERATURES2(m, raw);
            (void)thermal_bench_temperatures2_pack(frame->data, &m, 8u);
            tx_finish(frame, THERMAL_BENCH_TEMPERATURES2_FRAME_ID, NODE_TX_TEMPERATURES2,
                      NODE_DATA_ID_TEMPERATURES2);
        }
    }
}

/* TargetNode._timing_frames: Timing1 (measured), Timing2 and Timing3 (the C28x estimate), Timing4 (M4 cycles). */
static void send_timing(uint16_t step, uint32_t cycles)
{
    /* 0.1 us at NODE_CLOCK_HZ, rounded to nearest (an odd divisor such as 9 at 90 MHz has no ties) */
    const uint32_t tenths_us = (cycles + NODE_CYCLES_PER_TENTH_US / 2u) / NODE_CYCLES_PER_TENTH_US;
    struct node_frame *frame;
    if ((frame = tx_slot()) != NULL) {
        struct thermal_bench_timing1_t m;
        thermal_bench_timing1_init(&m);
        m.timing1_counter = tx_counter[NODE_TX_TIMING1];
        m.timing1_step = step;
        m.step_time_measured = clamp_u32(tenths_us, NODE_STEP_TIME_MEASURED_MAX);
        m.overruns = saturate8(node_counters.overruns);   /* after all of the row's steps */
        (void)thermal_bench_timing1_pack(frame->data, &m, 8u);
        tx_finish(frame, THERMAL_BENCH_TIMING1_FRAME_ID, NODE_TX_TIMING1, NODE_DATA_ID_TIMING1);
    }
    if ((frame = tx_slot()) != NULL) {
        struct thermal_bench_timing2_t m;
        thermal_bench_timing2_init(&m);
        m.timing2_counter = tx_counter[NODE_TX_TIMING2];
        m.timing2_step = step;
        m.est_cycles = NODE_EST_CYCLES_RAW;
        m.est_exec_time = NODE_EST_EXEC_TIME_RAW;
        (void)thermal_bench_timing2_pack(frame->data, &m, 8u);
        tx_finish(frame, THERMAL_BENCH_TIMING2_FRAME_ID, NODE_TX_TIMING2, NODE_DATA_ID_TIMING2);
    }
    if ((frame = tx_slot()) != NULL) {
        struct thermal_bench_timing3_t m;
        thermal_bench_timing3_init(&m);
        m.timing3_counter = tx_counter[NODE_TX_TIMING3];
        m.timing3_step = step;
        m.cpu_load = NODE_CPU_LOAD_RAW;
        (void)thermal_bench_timing3_pack(frame->data, &m, 8u);
        tx_finish(frame, THERMAL_BENCH_TIMING3_FRAME_ID, NODE_TX_TIMING3, NODE_DATA_ID_TIMING3);
    }
    if ((frame = tx_slot()) != NULL) {
        struct thermal_bench_timing4_t m;
        thermal_bench_timing4_init(&m);
        m.timing4_counter = tx_counter[NODE_TX_TIMING4];
        m.timing4_step = step;
        m.m4_cycles = clamp_u32(cycles, NODE_M4_CYCLES_MAX);
        m.m4_exec_time = (uint16_t)clamp_u32(tenths_us, NODE_M4_EXEC_TIME_MAX);
        (void)thermal_bench_timing4_pack(frame->data, &m, 8u);
        tx_finish(frame, THERMAL_BENCH_TIMING4_FRAME_ID, NODE_TX_TIMING4, NODE_DATA_ID_TIMING4);
    }
#ifdef NODE_WITH_ISR
}

/* Timing5: the step's response time (0.1 us at NODE_CLOCK_HZ) and the interrupt's CPU load. */
static void send_response(uint16_t step, uint32_t response, uint32_t load)
{
    struct node_frame *frame;
    if ((frame = tx_slot()) != NULL) {
        struct thermal_bench_timing5_t m;
        thermal_bench_timing5_init(&m);
        m.timing5_counter = tx_counter[NODE_TX_TIMING5];
        m.timing5_step = step;
        m.response_time = clamp_u32((response + NODE_CYCLES_PER_TENTH_US / 2u) / NODE_CYCLES_PER_TENTH_US,
                                    NODE_RESPONSE_TIME_MAX);
        m.isr_load = (uint16_t)clamp_u32(load, NODE_ISR_LOAD_MAX);
        (void)thermal_bench_timing5_pack(frame->data, &m, 8u);
        tx_finish(frame, THERMAL_BENCH_TIMING5_FRAME_ID, NODE_TX_TIMING5, NODE_DATA_ID_TIMING5);
    }
#endif
}

/* Every one of the n values inside the DBC's checkpoint range (NaN is not): a checkpoint is sent whole or not at
 * all (TargetNode._checkpoint_frames, _observer_checkpoint_frames). */
static int values_in_state_range(const float values[], unsigned int n)
{
    unsigned int i;
    for (i = 0; i < n; i++) {     /* wcet-loop: max(NODE_STATE_SIZE, NODE_OBS_CHECKPOINT_SIZE) */
        if (!(values[i] >= NODE_STATE_VALUE_MIN && values[i] <= NODE_STATE_VALUE_MAX)) return 0;     /* NaN too */
    }
    return 1;
}

#ifdef FW_OBSERVER
/* TargetNode._observer_checkpoint_frames: the filter's checkpoint (fw_obs_checkpoint), one element per frame with
 * its Index and StepLow; none when an element is outside the DBC range (a restore then starts P at P0). */
static void send_observer_checkpoint(uint16_t step)
{
    static float values[OBS_CHECKPOINT_SLOTS];              /* .bss, not the node's stack */
    unsigned int i;
    fw_obs_checkpoint(values);
    if (!values_in_state_range(values, NODE_OBS_CHECKPOINT_SIZE)) return;
    for (i = 0; i < NODE_OBS_CHECKPOINT_SIZE; i++) {
        struct thermal_bench_observer_checkpoint_t m;
        struct node_frame *frame = tx_slot();
        if (frame == NULL) return;
        thermal_bench_observer_checkpoint_init(&m);
        m.observer_checkpoint_counter = tx_counter[NODE_TX_OBSERVER_CHECKPOINT];
        m.observer_checkpoint_index = (uint8_t)i;
        m.observer_checkpoint_step_low = (uint16_t)(step % NODE_CHECKPOINT_STEP_LOW_MODULO);
        m.observer_checkpoint_value = values[i];
        (void)thermal_bench_observer_checkpoint_pack(frame->data, &m, 8u);
        tx_finish(frame, THERMAL_BENCH_OBSERVER_CHECKPOINT_FRAME_ID, NODE_TX_OBSERVER_CHECKPOINT,
                  NODE_DATA_ID_OBSERVER_CHECKPOINT);
    }
}
#endif

/* TargetNode._checkpoint_frames: x after this row's model step; none if an element is outside the DBC range. */
static void send_checkpoint(uint16_t step)
{
    float x[NODE_STATE_SIZE];
    unsigned int i;
    fw_state(x);
    if (!values_in_state_range(x, NODE_STATE_SIZE)) return;
    for (i = 0; i < NODE_STATE_SIZE; i++) {
        struct thermal_bench_state_checkpoint_t m;
        struct node_frame *frame = tx_slot();
        if (frame == NULL) return;
        thermal_bench_state_checkpoint_init(&m);
        m.state_checkpoint_counter = tx_counter[NODE_TX_STATE_CHECKPOINT];
        m.state_checkpoint_step = step;
        m.state_checkpoint_state_index = (uint8_t)i;
        m.state_checkpoint_state_value = x[i];
        (void)thermal_bench_state_checkpoint_pack(frame->data, &m, 8u);
        tx_finish(frame, THERMAL_BENCH_STATE_CHECKPOINT_FRAME_ID, NODE_TX_STATE_CHECKPOINT,
                  NODE_DATA_ID_STATE_CHECKPOINT);
    }
#ifdef FW_OBSERVER
    send_observer_checkpoint(step);
#endif
}

#ifdef FW_OBSERVER
/* observer.node._clamp, then the codec's exact rounding: NaN as the largest value, -inf (and below) as the least */
static int32_t clamped_raw(float value, float low, float high, int64_t inv, int64_t offset_raw, int32_t raw_low,
                           int32_t raw_high)
{
    if (!(value >= low)) return value != value ? raw_high : raw_low;
    if (!(value <= high)) return raw_high;
    return (int32_t)exact_raw(value, inv, offset_raw);
}

/* An innovation's raw value (NaN: not used, 0). */
static int32_t innovation_raw(float value)
{
    return is_finite(value) ? clamped_raw(value, NODE_INNOVATION_MIN, NODE_INNOVATION_MAX, NODE_INNOVATION_INV_SCALE,
                                          NODE_INNOVATION_OFFSET_RAW, NODE_INNOVATION_RAW_MIN, NODE_INNOVATION_RAW_MAX)
                            : 0;
}

/* TargetNode._observer_frames: Uncertainty1, Uncertainty2 (each node's 1-sigma) and Innovations after a model step
 * (report: fw_obs_report's sigma[4], then each measurement's innovation; NaN: not used, its slot's Used 0 and its
 * innovation 0; gate: fw_obs_gate's, each slot's Rejected in Innovations and Flagged in Uncertainty1). */
static void send_observer(uint16_t step, const float report[REPORT_WIDTH],
                          const unsigned char gate[NODE_OBS_MEASUREMENTS])
{
    uint32_t raw[NODE_STATE_SIZE];
    struct node_frame *frame;
    unsigned int i;
    for (i = 0; i < NODE_STATE_SIZE; i++) {
        raw[i] = (uint32_t)clamped_raw(report[i], NODE_SIGMA_MIN, NODE_SIGMA_MAX, NODE_SIGMA_INV_SCALE,
                                       NODE_SIGMA_OFFSET_RAW, NODE_SIGMA_RAW_MIN, NODE_SIGMA_RAW_MAX);
    }
    if ((frame = tx_slot()) != NULL) {
        struct thermal_bench_uncertainty1_t m;
        thermal_bench_uncertainty1_init(&m);
        m.uncertainty1_counter = tx_counter[NODE_TX_UNCERTAINTY1];
        m.uncertainty1_step = step;
        NODE_FILL_UNCERTAINTY1(m, raw);
        NODE_FILL_GATE_FLAGS(m, gate);
        (void)thermal_bench_uncertainty1_pack(frame->data, &m, 8u);
        tx_finish(frame, THERMAL_BENCH_UNCERTAINTY1_FRAME_ID, NODE_TX_UNCERTAINTY1, NODE_DATA_ID_UNCERTAINTY1);
    }
    if ((frame = tx_slot()) != NULL) {
        struct thermal_bench_uncertainty2_t m;
        thermal_bench_uncertainty2_init(&m);
        m.uncertainty2_counter = tx_counter[NODE_TX_UNCERTAINTY2];
        m.uncertainty2_step = step;
        NODE_FILL_UNCERTAINTY2(m, raw);
        (void)thermal_bench_uncertainty2_pack(frame->data, &m, 8u);
        tx_finish(frame, THERMAL_BENCH_UNCERTAINTY2_FRAME_ID, NODE_TX_UNCERTAINTY2, NODE_DATA_ID_UNCERTAINTY2);
    }
    if ((frame = tx_slot()) != NULL) {
        struct thermal_bench_innovations_t m;
        thermal_bench_innovations_init(&m);
        m.innovations_counter = tx_counter[NODE_TX_INNOVATIONS];
        m.innovations_step = step;
        NODE_FILL_INNOVATIONS(m, report, gate);
        (void)thermal_bench_innovations_pack(frame->data, &m, 8u);
        tx_finish(frame, THERMAL_BENCH_INNOVATIONS_FRAME_ID, NODE_TX_INNOVATIONS, NODE_DATA_ID_INNOVATIONS);
    }
}

/* The measurement frames kept for the next row: none. */
static void measurements_forget(void)
{
    unsigned int i;
    for (i = 0; i < NODE_MEASUREMENT_MESSAGES; i++) measurement[i].have = 0u;
    measurement_arrivals = 0u;
}

/* TargetNode._measured, then NodeObserver.raw: the observer's raw channels of the row of `step` into
 * sample[NODE_ROW_WIDTH..] (NaN where no VALID value of that Step came); a measurement frame of another Step is a
 * sequence error, in the order the frames first came. */
static void sequence_error(uint8_t code, int32_t a, int32_t b);
#define WHY_OF(NAME, name, slot, why) why,
static const uint8_t measurement_why[NODE_MEASUREMENT_MESSAGES] = {NODE_MEASUREMENT_LIST(WHY_OF)};
static void measured(uint16_t step, float sample[NODE_SAMPLE_WIDTH])
{
    float channels[NODE_HOST_CHANNELS];
    unsigned int i, c, turn;
    for (c = 0; c < NODE_HOST_CHANNELS; c++) channels[c] = NO_READING;
    for (turn = 0; turn < measurement_arrivals; turn++) {  /* wcet-loop: NODE_MEASUREMENT_MESSAGES */
        for (i = 0; i < NODE_MEASUREMENT_MESSAGES; i++) {
            if (!measurement[i].have || measurement[i].order != turn) continue;
            if (measurement[i].step != step) {
                sequence_error(measurement_why[i], measurement[i].step, step);
                continue;
            }
            for (c = 0; c < NODE_HOST_CHANNELS; c++) {     /* a message's own channels only: the others are NaN */
                if (measurement[i].channels[c] == measurement[i].channels[c]) channels[c] = measurement[i].channels[c];
            }
        }
    }
    measurements_forget();
    NODE_OBS_RAW(sample, channels);
}

/* A measurement frame the observer reads: kept (its channels) for the row of its Step. */
static void measurement_frame(unsigned int slot, uint16_t step, const float channels[NODE_HOST_CHANNELS])
{
    unsigned int c;
    if (!measurement[slot].have) measurement[slot].order = measurement_arrivals++;
    measurement[slot].have = 1u;
    measurement[slot].step = step;
    for (c = 0; c < NODE_HOST_CHANNELS; c++) measurement[slot].channels[c] = channels[c];
}

/* TargetNode._restored_checkpoint and NodeObserver.restore: the filter from every RestoreObserver element of the
 * RESTORE's Step (StepLow), else P0; the elements are used up either way. */
static void observer_restore(const float x[NODE_STATE_SIZE], uint16_t step)
{
    static float values[OBS_CHECKPOINT_SLOTS];
    const uint16_t low = (uint16_t)(step % NODE_CHECKPOINT_STEP_LOW_MODULO);
    unsigned int i;
    int complete = 1;
    for (i = 0; i < NODE_OBS_CHECKPOINT_SIZE; i++) {
        if (!restore_observer[i].have || restore_observer[i].step_low != low) complete = 0;
        values[i] = restore_observer[i].value;
        restore_observer[i].have = 0u;
    }
    if (complete) {
        fw_obs_restore_checkpoint(x, values);
    } else {
        fw_obs_restore(x);
    }
}
#endif

/* ------------------------------------------------------------------------------------------------ state */
/* TargetNode._set_state: an extra Status at every change. */
static void set_state(uint8_t next)
{
    const uint8_t changed = (uint8_t)(next != state);
    state = next;
    if (changed) send_status();
}

/* TargetNode._sequence_error */
static void sequence_error(uint8_t code, int32_t a, int32_t b)
{
    node_counters.errors[NODE_KIND_SEQUENCE - 1]++;
    faults |= NODE_FAULT_SEQUENCE;
    record(NODE_KIND_SEQUENCE, code, a, b);
}

/* TargetNode._incomplete: a RESET or RESTORE without its data changes nothing of the model; IDLE. */
static void incomplete(uint8_t code, uint16_t step)
{
    faults |= NODE_FAULT_RESET_INCOMPLETE;
    record(NODE_KIND_INCOMPLETE, code, step, 0);
    set_state(NODE_STATE_IDLE);
}

/* RowAccumulator.reset */
static void rows_reset(void)
{
    fw_clear();
    have_last_inputs = 0u;
}

/* TargetNode._ready: after the model state was set by RESET or RESTORE. */
static void ready(void)
{
    fw_output(estimate);
    rows_reset();
    pending.count = 0u;
#ifdef FW_OBSERVER
    measurements_forget();
#endif
    running_rows = 0u;
    have_reply_row = 0u;
    node_counters.rows_used = node_counters.model_steps = node_counters.overruns = 0u;
    faults &= NODE_FAULT_NO_ARTIFACT;
    state = NODE_STATE_READY;
    send_target_info();
    send_status();
}

/* InputAccumulator.ends_interval: row k is the last sample of its model step's interval. The rule is periodic
 * in the row with period NODE_ROWS_PER_PERIOD (rows and steps in lowest terms), so the phase is enough. */
static int ends_interval(uint32_t row)
{
    const uint32_t phase = row % NODE_ROWS_PER_PERIOD;
    return (phase + 1u) * NODE_STEPS_PER_PERIOD / NODE_ROWS_PER_PERIOD
           != phase * NODE_STEPS_PER_PERIOD / NODE_ROWS_PER_PERIOD;
}

/* ------------------------------------------------------------------------------------------------ rows */
/* One model step on `inputs` (TargetNode._row's loop body); returns its DWT cycles. */
static uint32_t model_step(const float inputs[NODE_SAMPLE_WIDTH])
{
    uint32_t started, cycles;
    started = DWT_CYCCNT;
    MODEL_STEP(inputs, estimate);
#ifdef NODE_WITH_ISR
    step_ended = DWT_CYCCNT;                                /* the same one read after the step */
    cycles = step_ended - started;
#else
    cycles = DWT_CYCCNT - started;
#endif
    node_counters.model_steps++;
    if (cycles > NODE_DT_CYCLES) {
        node_counters.overruns++;
        faults |= NODE_FAULT_OVERRUN;
    }
    node_out.last_step_cycles = cycles;
    node_out.step_cycles += cycles;
    return cycles;
}

/* The model steps of one row whose timing frames (TIMING_FRAMES each) can be queued; a step beyond runs untimed on
 * the bus. */
#define TIMED_STEPS (NODE_REPLY_CAPACITY / (TIMING_FRAMES + OBSERVER_FRAMES))

#ifdef NODE_WITH_ISR
/* The step just run: its response time, and the interrupt's CPU load over the interrupts since the previous step:
 * their mean cycles over the period (C / T; float32: no 64-bit division without a libc). */
static void time_response(uint32_t index)
{
    const uint32_t busy = foc_busy_cycles, ticks = foc_ticks;
    response_of[index].response = step_ended - node_rx_stamp;
    response_of[index].load = ticks != ticks_since
        ? (uint32_t)((float)(busy - busy_since) / (float)(ticks - ticks_since) * foc_rate_hz
                     * (10000.0f / (float)NODE_CLOCK_HZ) + 0.5f)
        : 0u;
    ticks_since = ticks;
    busy_since = busy;
}
#endif

/* One model step of a row; its cycles kept for the row's timing frames while they fit, else those are counted as
 * dropped. */
static void step_on(const float inputs[NODE_SAMPLE_WIDTH], uint32_t cycles_of[TIMED_STEPS], uint32_t *steps)
{
    const uint32_t cycles = model_step(inputs);
    xcp_event(XCP_EVENT_MODEL_STEP);                        /* DAQ sampled right after its step */
    if (*steps < TIMED_STEPS) {
        cycles_of[*steps] = cycles;
#ifdef FW_OBSERVER
        fw_obs_report(report_of[*steps]);
        fw_obs_gate(gate_of[*steps]);
#endif
#ifdef NODE_WITH_ISR
        time_response(*steps);
#endif
    } else {
        node_out.tx_dropped += TIMING_FRAMES + OBSERVER_FRAMES;    /* its frames could not be queued anyway */
    }
    (*steps)++;
}

/* RowAccumulator.skip's means and the steps on them, one by one (no list: bounded RAM), then the row's own. */
static void handle_row(uint16_t step, const float sample[NODE_SAMPLE_WIDTH])
{
    const uint32_t expected = next_row;
    const uint16_t ahead = (uint16_t)(step - (uint16_t)expected);       /* mod 2^16 */
    uint32_t row, lost, cycles_of[TIMED_STEPS];
    uint32_t steps = 0u;
    float mean[NODE_SAMPLE_WIDTH];
    if (state != NODE_STATE_RUNNING || !running_rows) {
        sequence_error(NODE_WHY_ROW_STATE, step, state);
        return;
    }
    if (have_reply_row && step == last_reply_step) {        /* the host sent the last row again: answer again */
        node_counters.repeats++;
        node_out.answered_again = 1u;
        send_temperatures(step);
        return;
    }
    if (ahead >= NODE_STEP_MODULO / 2u) {
        sequence_error(NODE_WHY_ROW_BACK, step, (uint16_t)expected);
        return;
    }
    row = expected + ahead;
    if (ahead) sequence_error(NODE_WHY_ROWS_LOST, (uint16_t)expected, (uint16_t)(row - 1u));
    for (lost = expected; lost < row; lost++) {             /* RowAccumulator.skip */ /* wcet-loop: lost_rows */
        if (!ends_interval(lost)) continue;
        if (fw_mean(mean)) {                                /* the rows of the interval that did arrive */
            memcpy(last_inputs, mean, sizeof mean);
            have_last_inputs = 1u;
        } else if (have_last_inputs) {
            memcpy(mean, last_inputs, sizeof mean);         /* none did: hold the previous step's inputs */
#ifdef FW_OBSERVER
            {                                               /* but not its measurements: that step predicts only */
                unsigned int c;
                for (c = NODE_ROW_WIDTH; c < NODE_SAMPLE_WIDTH; c++) mean[c] = NO_READING;
            }
#endif
        } else {
            continue;                                       /* nothing ever arrived: no inputs to step on */
        }
        step_on(mean, cycles_of, &steps);
    }
    next_row = row + 1u;
    node_counters.rows_used++;
    fw_accumulate(sample);                                  /* RowAccumulator.add */
    if (ends_interval(row) && fw_mean(mean)) {
        memcpy(last_inputs, mean, sizeof mean);
        have_last_inputs = 1u;
        step_on(mean, cycles_of, &steps);
    }
    send_temperatures(step);
    last_reply_step = step;
    have_reply_row = 1u;
    {
        uint32_t i;
        for (i = 0u; i < steps && i < TIMED_STEPS; i++) {  /* wcet-loop: steps_per_row */
            send_timing(step, cycles_of[i]);
#ifdef NODE_WITH_ISR
            send_response(step, response_of[i].response, response_of[i].load);
#endif
#ifdef FW_OBSERVER
            send_observer(step, report_of[i], gate_of[i]);
#endif
        }
    }
    if (steps && node_counters.model_steps % NODE_CHECKPOINT_EVERY == 0u) send_checkpoint(step);
}

/* ------------------------------------------------------------------------------------------------ control */
/* TargetNode._control */
static void control(uint8_t command, uint16_t step)
{
    if (command == NODE_COMMAND_RESET) {
        float y0[NODE_STATE_SIZE];
        unsigned int i;
        int complete = 1;
        for (i = 0; i < NODE_RESET_MESSAGES; i++) {         /* each message's last frame, of this Step */
            if (!reset_frames[i].have || reset_frames[i].step != step) complete = 0;
            reset_frames[i].have = 0u;
        }
        if (!complete) {
            incomplete(NODE_WHY_RESET_INCOMPLETE, step);
            return;
        }
        NODE_RESET_TEMPERATURES(y0, reset_frames);
        MODEL_RESET(y0);
        ready();
    } else if (command == NODE_COMMAND_RESTORE) {
        float x[NODE_STATE_SIZE];
        unsigned int i;
        int complete = 1;
        for (i = 0; i < NODE_STATE_SIZE; i++) {
            if (!restore_frames[i].have || restore_frames[i].step != step) complete = 0;
            x[i] = restore_frames[i].value;
            restore_frames[i].have = 0u;
        }
        if (!complete) {
            incomplete(NODE_WHY_RESTORE_INCOMPLETE, step);
            return;
        }
#ifdef FW_OBSERVER
        observer_restore(x, step);
#else
        MODEL_RESTORE(x);
#endif
        ready();
    } else if (command == NODE_COMMAND_START) {
        if (state != NODE_STATE_READY) {
            sequence_error(NODE_WHY_START_STATE, state, 0);
            return;
        }
        next_row = step;
        running_rows = 1u;
        set_state(NODE_STATE_RUNNING);
    } else if (command == NODE_COMMAND_STOP) {
        int i;
        for (i = 0; i < RX_COUNT; i++) counter_known[i] = 0u;     /* FrameValidator.reset_counters */
        pending.count = 0u;
#ifdef FW_OBSERVER
        measurements_forget();
#endif
        set_state(NODE_STATE_STOPPED);
    }
}

/* ------------------------------------------------------------------------------------------------ receiving */
static void reject(uint8_t kind, uint8_t code, int32_t a, int32_t b)
{
    node_counters.errors[kind - 1u]++;
    faults |= NODE_FAULT_RX_ERROR;
    record(kind, code, a, b);
}

/* A received frame, unpacked once by the generated unpack function of its message (`validate`). */
#define RX_MEMBER(NAME, name, id) struct thermal_bench_##name##_t name;
union rx_signals {
    NODE_RX_LIST(RX_MEMBER)
};

#define RX_UNPACK(NAME, name, id)                                                                                     \
    case RX_##NAME: (void)thermal_bench_##name##_unpack(&m->name, data, 8u); break;
static void unpack(int index, const uint8_t *data, union rx_signals *m)
{
    switch (index) {
    NODE_RX_LIST(RX_UNPACK)
    default: break;
    }
}

/* TargetNode._row_frame's rules for the `index`-th frame of a data row (NODE_ROW_INDEX_*), of Step `step`: 1 when
 * it continues the pending row (the caller decodes it into pending.sample, then calls row_frame_done), 0 after a
 * sequence error (the pending row forgotten). */
static int row_frame(unsigned int index, uint16_t step)
{
    const uint8_t count = pending.count;
    if (index == 0u) {                                      /* a new row; an unfinished one is an error */
        if (count) sequence_error(NODE_WHY_ROW_UNFINISHED, pending.step, count);
        pending.count = 0u;
        pending.step = step;
        return 1;
    }
    if (count != index) {                                   /* not the next frame of the row */
        pending.count = 0u;
        if (count < index) {
            sequence_error(NODE_WHY_ROW_WITHOUT, step, count);
        } else {
            sequence_error(NODE_WHY_ROW_UNFINISHED, pending.step, count);
        }
        return 0;
    }
    if (pending.step != step) {                             /* of another row */
        pending.count = 0u;
        sequence_error(NODE_WHY_ROW_STEPS, pending.step, step);
        return 0;
    }
    return 1;
}

/* The `index`-th frame of the row is decoded: wait for the next one, or the row is complete and used. */
static void row_frame_done(unsigned int index, uint16_t step)
{
    if (index + 1u < NODE_ROW_MESSAGES) {
        pending.count = (uint8_t)(index + 1u);
        return;
    }
    pending.count = 0u;
#ifdef FW_OBSERVER
    measured(step, pending.sample);                         /* TargetNode._row_frame: the row's raw channels */
#endif
    handle_row(step, pending.sample);
}

/* One frame of a data row: MESSAGE (DRIVE_INPUTS, ...) with its signals in `m` (fw_node_config.h's macros). */
#define ROW_FRAME(MESSAGE, m)                                                                                         \
    do {                                                                                                              \
        if (row_frame(NODE_ROW_INDEX_##MESSAGE, NODE_STEP_##MESSAGE(m))) {                                             \
            NODE_DECODE_##MESSAGE(pending.sample, m);                                                                 \
            row_frame_done(NODE_ROW_INDEX_##MESSAGE, NODE_STEP_##MESSAGE(m));                                          \
        }                                                                                                             \
    } while (0)

/* RESET's `slot`-th message (NODE_RESET_LIST): its last frame kept until the RESET. */
#define RESET_FRAME(NAME, name, slot)                                                                                 \
    case RX_##NAME:                                                                                                   \
        reset_frames[slot].have = 1u;                                                                                 \
        reset_frames[slot].step = NODE_STEP_##NAME(m->name);                                                          \
        NODE_RESET_RAW_##NAME(reset_frames[slot].raw, m->name);                                                       \
        break;
#define ROW_CASE(NAME, name) case RX_##NAME: ROW_FRAME(NAME, m->name); break;
#ifdef FW_OBSERVER
/* A measurement frame the observer reads (NODE_MEASUREMENT_LIST): its channels kept for the row of its Step. */
#define MEASUREMENT_CASE(NAME, name, slot, why)                                                                       \
    case RX_##NAME: {                                                                                                 \
        float channels[NODE_HOST_CHANNELS];                                                                           \
        unsigned int c;                                                                                               \
        for (c = 0; c < NODE_HOST_CHANNELS; c++) channels[c] = NO_READING;                                            \
        NODE_CHANNELS_##NAME(channels, m->name);                                                                      \
        measurement_frame(slot, NODE_STEP_##NAME(m->name), channels);                                                 \
        break;                                                                                                        \
    }
#endif

/* The application part of a valid frame (TargetNode._dispatch). */
static void dispatch(int index, const union rx_signals *m)
{
    switch (index) {
    NODE_ROW_LIST(ROW_CASE)                                 /* the model's data row (an electrical one: currents) */
    NODE_RESET_LIST(RESET_FRAME)
    case RX_RESTORE_STATE: {
        const uint8_t i = m->restore_state.restore_state_state_index;    /* 0..3: checked by the range check */
        restore_frames[i].have = 1u;
        restore_frames[i].step = NODE_STEP_RESTORE_STATE(m->restore_state);
        restore_frames[i].value = m->restore_state.restore_state_state_value;
        break;
    }
    case RX_CONTROL:
        control(m->control.command, NODE_STEP_CONTROL(m->control));
        break;
#ifdef FW_OBSERVER
    NODE_MEASUREMENT_LIST(MEASUREMENT_CASE)                 /* kept for the row of its Step */
    case RX_RESTORE_OBSERVER: {                             /* kept for the next RESTORE, by Index */
        const uint8_t i = m->restore_observer.restore_observer_index;
        if (i < NODE_OBS_CHECKPOINT_SIZE) {                 /* the others are no element of this filter */
            restore_observer[i].have = 1u;
            restore_observer[i].step_low = m->restore_observer.restore_observer_step_low;
            restore_observer[i].value = m->restore_observer.restore_observer_value;
        }
        break;
    }
#endif
    default:            /* a frame no rule acts on (BenchEvent, unread DriveCurrents, ...): validated only */
        break;
    }
}

/* The first signal of a frame outside its DBC range, as its index in the message (DBC order), or -1
 * (FrameValidator's range check: NODE_OUT_OF_RANGE_<NAME>, limits from the DBC's ranges). */
#define RX_RANGE(NAME, name, id) case RX_##NAME: return NODE_OUT_OF_RANGE_##NAME(m->name);
static int out_of_range_signal(int index, const union rx_signals *m)
{
    switch (index) {
    NODE_RX_LIST(RX_RANGE)
    default: return -1;
    }
}

/* Any id of the DBC (to tell "not received here" from "not in the DBC"). */
static int in_dbc(uint32_t id)
{
    static const uint32_t ids[] = {NODE_DBC_FRAME_IDS};
    unsigned int i;
    for (i = 0u; i < sizeof ids / sizeof ids[0]; i++) {
        if (ids[i] == id) return 1;
    }
    return 0;
}

/* FrameValidator.validate, in the contract's order: id, DLC, CRC, ranges, alive counter; a valid frame's signals
 * are in `m`. */
static int validate(uint32_t id, uint32_t dlc, const uint8_t *data, union rx_signals *m)
{
    int index, signal;
    uint8_t crc, counter;
    if (id & NODE_ID_ERROR) {
        reject(NODE_KIND_UNKNOWN_ID, NODE_WHY_ERROR_FRAME, 0, 0);
        return -1;
    }
    if (id & NODE_ID_REMOTE) {
        reject(NODE_KIND_UNKNOWN_ID, NODE_WHY_REMOTE_FRAME, (int32_t)(id & 0x1FFFFFFFu), 0);
        return -1;
    }
    if (id & NODE_ID_EXTENDED) {
        reject(NODE_KIND_UNKNOWN_ID, NODE_WHY_EXTENDED_FRAME, (int32_t)(id & 0x1FFFFFFFu), 0);
        return -1;
    }
    if (id & NODE_ID_FD) {
        reject(NODE_KIND_UNKNOWN_ID, NODE_WHY_FD_FRAME, (int32_t)(id & 0x7FFu), 0);
        return -1;
    }
    for (index = 0; index < RX_COUNT && rx_ids[index] != id; index++) {
    }
    if (index == RX_COUNT) {
        reject(NODE_KIND_UNKNOWN_ID, in_dbc(id) ? NODE_WHY_NOT_RECEIVED : NODE_WHY_NOT_IN_DBC, (int32_t)id, 0);
        return -1;
    }
    if (dlc != 8u) {
        reject(NODE_KIND_WRONG_LENGTH, NODE_WHY_LENGTH, (int32_t)dlc, 0);
        return -1;
    }
    crc = profile2_crc(data, rx_data_ids[index]);
    if (data[0] != crc) {
        reject(NODE_KIND_CRC, NODE_WHY_CRC, data[0], crc);
        return -1;
    }
    unpack(index, data, m);
    signal = out_of_range_signal(index, m);
    if (signal >= 0) {
        reject(NODE_KIND_OUT_OF_RANGE, NODE_WHY_RANGE, signal, 0);
        return -1;
    }
    counter = (uint8_t)(data[1] & 0x0Fu);
    if (counter_known[index] && counter != (uint8_t)((counter_last[index] + 1u) % NODE_COUNTER_MODULO)) {
        const uint8_t last = counter_last[index];
        counter_last[index] = counter;                          /* resynchronize: one lost frame, one error */
        reject(NODE_KIND_COUNTER, NODE_WHY_COUNTER, counter, last);
        return -1;
    }
    counter_known[index] = 1u;
    counter_last[index] = counter;
    return index;
}

/* ------------------------------------------------------------------------------------------------ entry points */
static void begin_call(void)
{
    node_out.tx_count = 0u;
    node_out.event_count = 0u;
    node_out.answered_again = 0u;
    node_out.step_cycles = 0u;
    rx_frame = NULL;
}

static void end_call(void)
{
    xcp_flush();                                            /* the DAQ packets after the call's replies */
    node_out.state = state;
    node_out.faults = faults;
    node_out.next_beat_ms = next_beat_ms;
}

void node_init(uint32_t now_ms)
{
    DEMCR |= 1u << 24;                                      /* TRCENA: the DWT on */
    DWT_CYCCNT = 0u;
    DWT_CTRL |= 1u;                                         /* CYCCNTENA */
#ifdef NODE_WITH_ISR
    ticks_since = foc_ticks;
    busy_since = foc_busy_cycles;
#endif
    memset(&node_out, 0, sizeof node_out);
    memset(&node_counters, 0, sizeof node_counters);
    memset(counter_known, 0, sizeof counter_known);
    memset(tx_counter, 0, sizeof tx_counter);
    memset(reset_frames, 0, sizeof reset_frames);
    memset(restore_frames, 0, sizeof restore_frames);
    memset(&pending, 0, sizeof pending);
#ifdef FW_OBSERVER
    memset(measurement, 0, sizeof measurement);
    measurement_arrivals = 0u;
    memset(restore_observer, 0, sizeof restore_observer);
#endif
    memset(estimate, 0, sizeof estimate);
    running_rows = have_reply_row = have_last_inputs = 0u;
    next_row = 0u;
    fw_clear();
    xcp_init();
    state = NODE_STATE_IDLE;
    faults = 0u;
    begin_call();
    send_target_info();                                     /* TargetNode.startup_frames */
    send_status();
    send_rx_errors();
    next_beat_ms = now_ms + NODE_HEARTBEAT_MS;
    end_call();
}

void node_on_frame(uint32_t id, uint32_t dlc, const uint8_t *data)
{
    union rx_signals m;
    int index;
    begin_call();
    node_counters.frames_received++;
    rx_frame = &node_rx;
    if (data != node_rx.data) {                             /* a frame not in the mailbox: judge a copy of it */
        node_rx.id = id;
        node_rx.dlc = dlc;
        memcpy(node_rx.data, data, dlc < 8u ? dlc : 8u);
    }
    index = validate(id, dlc, node_rx.data, &m);
    if (index >= 0) dispatch(index, &m);
    end_call();
}

void node_on_xcp(uint32_t dlc, const uint8_t *data)
{
    begin_call();
    xcp_command(dlc, data);
    end_call();
}

void node_on_tick(uint32_t now_ms)
{
    begin_call();
    if ((int32_t)(now_ms - next_beat_ms) >= 0) {            /* serve()'s heartbeat schedule */
        send_status();
        send_rx_errors();
        xcp_event(XCP_EVENT_HEARTBEAT);                     /* the XCP time event */
        next_beat_ms += NODE_HEARTBEAT_MS;
        if ((int32_t)(next_beat_ms - now_ms) <= 0) next_beat_ms = now_ms + NODE_HEARTBEAT_MS;
    }
    end_call();
}

void node_internal_fault(uint32_t code)
{
    begin_call();
    faults |= NODE_FAULT_INTERNAL;
    record(NODE_KIND_INTERNAL, (uint8_t)code, 0, 0);
    set_state(NODE_STATE_FAULT);
    end_call();
}
