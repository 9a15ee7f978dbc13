/* xcp.c - the firmware node's XCP-on-CAN slave (ASAM MCD-1 XCP 1.x): target_sim/xcp's command processor, in C99.
 *
 * Included by node.c (one translation unit: it queues its packets with node.c's tx_slot); node_on_xcp calls it. The Python slave
 * (target_sim.xcp: commands.py, daq.py, memory.py) is the reference; each function names what it mirrors, and the
 * conformance test sends one command sequence to both engines and compares the reply bytes. Every fact comes from
 * fw_node_config.h (nodegen.py's _xcp_macros): the CAN ids (dbc/xcp.toml), the protocol's numbers
 * (target_sim.xcp.codes), the DAQ tables' budget (target_sim.xcp.daq), the GET_ID texts, and the cells
 * (XCP_CELL_LIST: every cell of the Python node's catalogue that the C has a variable for, with its writability and
 * float32 limits). The address space is the image's own RAM and flash at those variables' addresses, so UPLOAD,
 * DAQ and BUILD_CHECKSUM read the bytes the model computes with, and DOWNLOAD writes the variable the model reads
 * (fw_cal_alpha_cu; an observer's obs_offset_<k>, obs_lag_pole_<k>, obs_r_<k>, obs_q): the addresses the A2L gives
 * (`bench firmware a2l --elf`).
 *
 * Commands: CONNECT, DISCONNECT, GET_STATUS, SYNCH, GET_COMM_MODE_INFO, GET_ID, SET_MTA, UPLOAD, SHORT_UPLOAD,
 * DOWNLOAD, BUILD_CHECKSUM (XCP_CRC_32), FREE_DAQ, ALLOC_DAQ, ALLOC_ODT, ALLOC_ODT_ENTRY, SET_DAQ_PTR, WRITE_DAQ,
 * SET_DAQ_LIST_MODE, START_STOP_DAQ_LIST, START_STOP_SYNCH, GET_DAQ_PROCESSOR_INFO, GET_DAQ_RESOLUTION_INFO;
 * anything else ERR_CMD_UNKNOWN. A command other than CONNECT while disconnected gets no answer.
 *
 * DAQ packets of an event are sampled when it happens (xcp_event: after each model step, on the heartbeat tick)
 * into a queue of XCP_DAQ_QUEUE packets (one per ODT of the tables: a step's packets always fit) and go out after
 * the call's other frames (xcp_flush, from end_call), as the Python node sends them after a row's replies. A row
 * that runs several model steps (lost rows) queues the packets of its steps in order while they fit; those past the
 * queue are dropped and counted in node_out.tx_dropped, as the Python slave drops and counts them
 * (XcpSlave.queued).
 *
 * The DAQ path's loops are bounded by `daq_lists` and `daq_odts` (target_sim.firmware.wcet.loop_facts): the DAQ
 * lists and ODTs a master configured, 0 without one, the tables' whole budget for the bound with XCP
 * (bench.firmware.timing.XCP_MODES, tests/benchmarks/bench_xcp.py).
 *
 * Without an XCP master since power-on (a drive run: `bench firmware timing`'s first mode), the globals marked
 * `wcet-value(no_master)` keep their power-on 0 (target_sim.firmware.wcet.value_facts; the WCET analysis then
 * knows which way the tests of them branch): xcp_connected is set only by CONNECT, daq_lists/daq_odts only by
 * ALLOC_DAQ/ALLOC_ODT, all commands that only node_on_xcp dispatches; daq_queued grows only in daq_sample, which
 * only xcp_event calls, after its test of xcp_connected. All four are 0 at power-on (.bss; xcp_init sets three of
 * them again). So xcp_event returns at that test and xcp_flush sends nothing.
 *
 * Flash: the functions called from several places are kept out of line (noinline): the node's entry points share
 * one copy instead of each inlining its own.
 */

/* what a calibration tool reads and writes: float32 cells at the addresses of the C's variables */
struct xcp_cell {
    float *at;
    uint8_t writable;
    float low, high;                  /* a writable cell's limits (float32: those the Python's double ones accept) */
};
#define XCP_CELL(at, writable, low, high) {at, writable, low, high},
static const struct xcp_cell xcp_cells[XCP_CELLS] = {XCP_CELL_LIST(XCP_CELL)};

/* GET_ID's texts, uploaded from the MTA: the ASCII identification (the A2L's EPK), then the A2L's name */
const char xcp_identification[XCP_ID_LENGTH + 1u] = XCP_ID_TEXT;   /* the NUL is not mapped */

/* what the shell reads for the node's statistics (target_sim.firmware.node_engine) */
struct xcp_counters {
    uint32_t commands;                /* commands answered (CONNECT included) */
    uint32_t errors;                  /* ERR packets */
    uint32_t ignored;                 /* commands while disconnected */
    uint32_t daq_packets;             /* DAQ packets sampled */
    uint32_t calibrations;            /* accepted DOWNLOADs */
    uint32_t samples;                 /* DAQ events that sampled a packet at least */
    uint32_t sample_cycles;           /* their DWT cycles, summed */
};
struct xcp_counters xcp_counters;

static uint8_t xcp_connected;             /* wcet-value(no_master): xcp_connected = 0 */
static uint32_t xcp_mta;

/* ---- the DAQ tables (daq.py's Daq): lists, ODTs by absolute number (a list's first PID + its index), entries */
enum { DAQ_FREE, DAQ_LISTS, DAQ_ODTS, DAQ_ENTRIES };   /* the allocation order: FREE_DAQ, ALLOC_DAQ, ... */
static struct {
    uint8_t odts;
    uint8_t first_pid;
    uint8_t event;
    uint8_t prescaler;
    uint8_t mode;
    uint8_t selected;
    uint8_t running;
    uint8_t countdown;
} daq_list[XCP_MAX_DAQ_LISTS];
static struct {
    uint8_t owner;                    /* its list */
    uint8_t capacity;                 /* entries allocated */
    uint8_t length;                   /* entries written or skipped (the Python list's length) */
    uint8_t complete;                 /* length == capacity, every entry written (Daq._complete, per ODT) */
    uint8_t size[XCP_ODT_PAYLOAD];    /* 0: skipped, never written */
    uint32_t address[XCP_ODT_PAYLOAD];
    uint8_t bytes;                    /* the packet's payload: its entries' bytes in order, by address */
    const uint8_t *byte_at[XCP_ODT_PAYLOAD];
} daq_odt[XCP_MAX_ODTS];
static uint32_t daq_lists, daq_odts, daq_stage, daq_allocated;   /* wcet-value(no_master): daq_lists = 0, daq_odts = 0 */
static uint8_t daq_have_pointer, daq_pointer_list, daq_pointer_odt, daq_pointer_entry;
static struct {
    uint8_t dlc;
    uint8_t data[8];
} daq_queue[XCP_DAQ_QUEUE];
static uint32_t daq_queued;                /* wcet-value(no_master): daq_queued = 0 */

/* ------------------------------------------------------------------------------------------------ helpers */
static uint32_t xcp_u16(const uint8_t *p) { return (uint32_t)p[0] | (uint32_t)p[1] << 8; }
static uint32_t xcp_u32(const uint8_t *p) { return xcp_u16(p) | xcp_u16(p + 2) << 16; }

static void xcp_put32(uint8_t *p, uint32_t value)
{
    p[0] = (uint8_t)value;
    p[1] = (uint8_t)(value >> 8);
    p[2] = (uint8_t)(value >> 16);
    p[3] = (uint8_t)(value >> 24);
}

static uint32_t cell_address(unsigned int i) { return (uint32_t)(uintptr_t)xcp_cells[i].at; }

/* AddressSpace._cell_at: the cell holding `address`, or -1 */
static int xcp_cell_at(uint32_t address)
{
    unsigned int i;
    for (i = 0u; i < XCP_CELLS; i++) {                      /* wcet-loop: XCP_CELLS */
        if (address - cell_address(i) < 4u) return (int)i;
    }
    return -1;
}

/* AddressSpace.read's rule: how many of the `want` bytes from `address` on are mapped (cells and the
 * identification, no gap between them); want when all are. */
static uint32_t xcp_mapped(uint32_t address, uint32_t want)
{
    const uint32_t text = (uint32_t)(uintptr_t)xcp_identification;
    uint32_t done = 0u;
    unsigned int piece;
    for (piece = 0u; piece < XCP_PIECES && done < want; piece++) {  /* wcet-loop: XCP_PIECES */
        const uint32_t at = address + done;
        const int cell = xcp_cell_at(at);
        if (cell >= 0) {
            done += 4u - (at - cell_address((unsigned int)cell));
        } else if (at - text < XCP_ID_LENGTH) {
            done += XCP_ID_LENGTH - (at - text);
        } else {
            break;
        }
    }
    return done < want ? done : want;
}

static int xcp_readable(uint32_t address, uint32_t size) { return xcp_mapped(address, size) == size; }

static const uint8_t *xcp_bytes(uint32_t address) { return (const uint8_t *)(uintptr_t)address; }

/* `n` bytes (at most a CAN frame's 8), with a loop the WCET analysis has a bound for (memcpy's has none) */
static void xcp_copy(uint8_t *to, const uint8_t *from, uint32_t n)
{
    uint32_t i;
    for (i = 0u; i < n && i < 8u; i++) to[i] = from[i];    /* wcet-loop: 8 */
}

/* ------------------------------------------------------------------------------------------------ replies */
static uint8_t xcp_reply[8];
static uint32_t xcp_reply_length;

static uint32_t xcp_error(uint32_t code)
{
    xcp_counters.errors++;
    xcp_reply[0] = (uint8_t)XCP_PID_ERR;
    xcp_reply[1] = (uint8_t)code;
    xcp_reply_length = 2u;
    return 0u;
}

/* a positive response of `length` bytes after its PID (already in xcp_reply[1..]) */
static uint32_t xcp_ok(uint32_t length)
{
    xcp_reply[0] = (uint8_t)XCP_PID_RES;
    xcp_reply_length = 1u + length;
    return 0u;
}

/* ------------------------------------------------------------------------------------------------ memory */
static uint32_t xcp_get_id(const uint8_t *cto)
{
    uint32_t length;
    if (cto[1] == XCP_ID_ASCII) {
        xcp_mta = (uint32_t)(uintptr_t)xcp_identification;
        length = XCP_ID_ASCII_LENGTH;
    } else if (cto[1] == XCP_ID_A2L_NAME) {
        xcp_mta = (uint32_t)(uintptr_t)xcp_identification + XCP_ID_ASCII_LENGTH;
        length = XCP_ID_LENGTH - XCP_ID_ASCII_LENGTH;
    } else {
        return xcp_error(XCP_ERR_OUT_OF_RANGE);
    }
    xcp_reply[1] = xcp_reply[2] = xcp_reply[3] = 0u;
    xcp_put32(xcp_reply + 4, length);
    return xcp_ok(7u);
}

/* UPLOAD and SHORT_UPLOAD: `size` bytes from `address`, the MTA after them */
static uint32_t xcp_upload(uint32_t size, uint32_t address)
{
    if (size < 1u || size > XCP_MAX_CTO - 1u) return xcp_error(XCP_ERR_OUT_OF_RANGE);
    if (!xcp_readable(address, size)) return xcp_error(XCP_ERR_ACCESS_DENIED);
    xcp_copy(xcp_reply + 1, xcp_bytes(address), size);
    xcp_mta = address + size;
    return xcp_ok(size);
}

/* DOWNLOAD (AddressSpace.write): whole calibratable cells, each value within its limits, checked first */
static uint32_t xcp_download(const uint8_t *cto, uint32_t length)
{
    const uint32_t size = cto[1];
    float value;
    int cell;
    if (size < 1u || size > XCP_MAX_CTO - 2u || length < 2u + size)
        return xcp_error(size > XCP_MAX_CTO - 2u ? XCP_ERR_OUT_OF_RANGE : XCP_ERR_CMD_SYNTAX);
    if (size % 4u) return xcp_error(XCP_ERR_OUT_OF_RANGE);   /* size 4: one float32 cell is all a CTO holds */
    cell = xcp_cell_at(xcp_mta);
    if (cell < 0 || !xcp_cells[cell].writable) return xcp_error(XCP_ERR_ACCESS_DENIED);
    if (cell_address((unsigned int)cell) != xcp_mta) return xcp_error(XCP_ERR_OUT_OF_RANGE);
    memcpy(&value, cto + 2, 4u);
    if (!(value >= xcp_cells[cell].low && value <= xcp_cells[cell].high))   /* NaN fails both */
        return xcp_error(XCP_ERR_OUT_OF_RANGE);
    memcpy(xcp_cells[cell].at, cto + 2, 4u);
    xcp_counters.calibrations++;
    xcp_mta += size;
    return xcp_ok(0u);
}

/* BUILD_CHECKSUM: XCP_CRC_32 (the IEEE 802.3 CRC, zlib.crc32) of `size` bytes from the MTA */
static uint32_t xcp_checksum(const uint8_t *cto)
{
    const uint32_t size = xcp_u32(cto + 4);
    const uint8_t *bytes;
    uint32_t crc = 0xFFFFFFFFu, i;
    unsigned int bit;
    if (size < 1u || size > XCP_MAX_BLOCK) return xcp_error(XCP_ERR_OUT_OF_RANGE);
    if (!xcp_readable(xcp_mta, size)) return xcp_error(XCP_ERR_ACCESS_DENIED);
    bytes = xcp_bytes(xcp_mta);
    for (i = 0u; i < size; i++) {                           /* wcet-loop: XCP_MAPPED_BYTES */
        crc ^= bytes[i];
        for (bit = 0u; bit < 8u; bit++) crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
    xcp_mta += size;
    xcp_reply[1] = (uint8_t)XCP_CHECKSUM_CRC_32;
    xcp_reply[2] = xcp_reply[3] = 0u;
    xcp_put32(xcp_reply + 4, ~crc);
    return xcp_ok(7u);
}

/* ------------------------------------------------------------------------------------------------ DAQ */
static int daq_running(void)
{
    uint32_t d;
    for (d = 0u; d < daq_lists; d++) {                      /* wcet-loop: daq_lists */
        if (daq_list[d].running) return 1;
    }
    return 0;
}

/* Daq._complete of list `d` (d < 0: of every selected list) */
static int daq_complete(int32_t d)
{
    uint32_t o;
    for (o = 0u; o < daq_odts; o++) {                       /* wcet-loop: XCP_MAX_ODTS */
        const int32_t owner = daq_odt[o].owner;
        if ((owner == d || (d < 0 && daq_list[owner].selected)) && !daq_odt[o].complete) return 0;
    }
    return 1;
}

/* After its entries changed: whether ODT `o` is complete, and the addresses of its packet's bytes (so a sample is
 * one loop over at most XCP_ODT_PAYLOAD bytes) */
static __attribute__((noinline)) void daq_refresh(uint32_t o)
{
    uint32_t e, b, n = 0u;
    uint8_t complete = (uint8_t)(daq_odt[o].length == daq_odt[o].capacity);
    for (e = 0u; e < daq_odt[o].length; e++) {              /* wcet-loop: XCP_ODT_PAYLOAD */
        if (!daq_odt[o].size[e]) complete = 0u;
        for (b = 0u; b < daq_odt[o].size[e] && n < XCP_ODT_PAYLOAD; b++) {   /* wcet-loop: XCP_ODT_PAYLOAD */
            daq_odt[o].byte_at[n++] = xcp_bytes(daq_odt[o].address[e] + b);
        }
    }
    daq_odt[o].complete = complete;
    daq_odt[o].bytes = (uint8_t)n;
}

static uint32_t daq_alloc_daq(const uint8_t *cto)
{
    const uint32_t count = xcp_u16(cto + 2);
    if (daq_stage != DAQ_LISTS || daq_lists) return xcp_error(XCP_ERR_SEQUENCE);
    if (count > XCP_MAX_DAQ_LISTS) return xcp_error(XCP_ERR_MEMORY_OVERFLOW);
    {
        uint32_t d;
        for (d = 0u; d < XCP_MAX_DAQ_LISTS; d++) {          /* wcet-loop: XCP_MAX_DAQ_LISTS */
            daq_list[d].odts = daq_list[d].first_pid = daq_list[d].event = daq_list[d].mode = 0u;
            daq_list[d].selected = daq_list[d].running = daq_list[d].countdown = 0u;
            daq_list[d].prescaler = 1u;
        }
    }
    daq_lists = count;
    daq_odts = 0u;
    daq_stage = DAQ_ODTS;
    return xcp_ok(0u);
}

static uint32_t daq_alloc_odt(const uint8_t *cto)
{
    const uint32_t d = xcp_u16(cto + 2), count = cto[4];
    uint32_t total = 0u, i;
    if (daq_stage != DAQ_ODTS) return xcp_error(XCP_ERR_SEQUENCE);
    if (d >= daq_lists) return xcp_error(XCP_ERR_OUT_OF_RANGE);
    for (i = 0u; i < daq_lists; i++) total += daq_list[i].odts;    /* wcet-loop: XCP_MAX_DAQ_LISTS */
    if (total + count > XCP_MAX_ODTS) return xcp_error(XCP_ERR_MEMORY_OVERFLOW);
    daq_list[d].odts = (uint8_t)count;
    for (total = 0u, i = 0u; i < daq_lists; i++) {          /* wcet-loop: XCP_MAX_DAQ_LISTS */
        uint32_t k;
        daq_list[i].first_pid = (uint8_t)total;
        for (k = 0u; k < daq_list[i].odts; k++) {           /* wcet-loop: XCP_MAX_ODTS */
            daq_odt[total + k].owner = (uint8_t)i;          /* every ODT is empty until ALLOC_ODT_ENTRY */
            daq_odt[total + k].capacity = daq_odt[total + k].length = daq_odt[total + k].bytes = 0u;
            daq_odt[total + k].complete = 1u;
        }
        total += daq_list[i].odts;
    }
    daq_odts = total;
    return xcp_ok(0u);
}

static uint32_t daq_alloc_odt_entry(const uint8_t *cto)
{
    const uint32_t d = xcp_u16(cto + 2), k = cto[4], count = cto[5];
    uint32_t o;
    if (daq_stage != DAQ_ODTS && daq_stage != DAQ_ENTRIES) return xcp_error(XCP_ERR_SEQUENCE);
    if (d >= daq_lists || k >= daq_list[d].odts) return xcp_error(XCP_ERR_OUT_OF_RANGE);
    if (count > XCP_ODT_PAYLOAD) return xcp_error(XCP_ERR_OUT_OF_RANGE);
    o = daq_list[d].first_pid + k;
    if (daq_allocated - daq_odt[o].capacity + count > XCP_MAX_ODT_ENTRIES) return xcp_error(XCP_ERR_MEMORY_OVERFLOW);
    daq_allocated = daq_allocated - daq_odt[o].capacity + count;
    daq_odt[o].capacity = (uint8_t)count;
    daq_refresh(o);
    daq_stage = DAQ_ENTRIES;
    return xcp_ok(0u);
}

static uint32_t daq_set_pointer(const uint8_t *cto)
{
    const uint32_t d = xcp_u16(cto + 2), k = cto[4], e = cto[5];
    if (d >= daq_lists) return xcp_error(XCP_ERR_OUT_OF_RANGE);
    if (k >= daq_list[d].odts || e >= daq_odt[daq_list[d].first_pid + k].capacity)
        return xcp_error(XCP_ERR_OUT_OF_RANGE);
    if (daq_list[d].running) return xcp_error(XCP_ERR_DAQ_ACTIVE);
    daq_have_pointer = 1u;
    daq_pointer_list = (uint8_t)d;
    daq_pointer_odt = (uint8_t)k;
    daq_pointer_entry = (uint8_t)e;
    return xcp_ok(0u);
}

static uint32_t daq_write(const uint8_t *cto)
{
    const uint32_t size = cto[2], address = xcp_u32(cto + 4);
    uint32_t o, e, others = 0u, i;
    if (cto[1] != 0xFFu) return xcp_error(XCP_ERR_OUT_OF_RANGE);      /* no bit-wise entries */
    if (!daq_have_pointer) return xcp_error(XCP_ERR_SEQUENCE);
    o = daq_list[daq_pointer_list].first_pid + daq_pointer_odt;
    e = daq_pointer_entry;
    if (e >= daq_odt[o].capacity) return xcp_error(XCP_ERR_OUT_OF_RANGE);
    for (i = 0u; i < daq_odt[o].length; i++) {              /* wcet-loop: XCP_ODT_PAYLOAD */
        if (i != e) others += daq_odt[o].size[i];
    }
    if (size < 1u || others + size > XCP_ODT_PAYLOAD) return xcp_error(XCP_ERR_DAQ_CONFIG);
    if (!xcp_readable(address, size)) return xcp_error(XCP_ERR_ACCESS_DENIED);
    for (i = daq_odt[o].length; i < e; i++) daq_odt[o].size[i] = 0u;   /* skipped: written later or never */ /* wcet-loop: XCP_ODT_PAYLOAD */
    daq_odt[o].size[e] = (uint8_t)size;
    daq_odt[o].address[e] = address;
    if (e >= daq_odt[o].length) daq_odt[o].length = (uint8_t)(e + 1u);
    daq_refresh(o);
    daq_pointer_entry = (uint8_t)(e + 1u);                  /* WRITE_DAQ post-increments the pointer */
    return xcp_ok(0u);
}

static uint32_t daq_set_mode(const uint8_t *cto)
{
    const uint32_t mode = cto[1], d = xcp_u16(cto + 2), event = xcp_u16(cto + 4), prescaler = cto[6];
    if (d >= daq_lists) return xcp_error(XCP_ERR_OUT_OF_RANGE);
    if (mode & (XCP_MODE_DIRECTION_STIM | XCP_MODE_TIMESTAMP | XCP_MODE_PID_OFF))
        return xcp_error(XCP_ERR_MODE_NOT_VALID);
    if (event >= XCP_EVENTS || prescaler < 1u) return xcp_error(XCP_ERR_OUT_OF_RANGE);
    daq_list[d].mode = (uint8_t)mode;
    daq_list[d].event = (uint8_t)event;
    daq_list[d].prescaler = (uint8_t)prescaler;
    return xcp_ok(0u);
}

static uint32_t daq_start_stop_list(const uint8_t *cto)
{
    const uint32_t mode = cto[1], d = xcp_u16(cto + 2);
    if (d >= daq_lists) return xcp_error(XCP_ERR_OUT_OF_RANGE);
    if (mode > 2u) return xcp_error(XCP_ERR_MODE_NOT_VALID);
    if (mode == 1u && !daq_complete((int32_t)d)) return xcp_error(XCP_ERR_DAQ_CONFIG);
    if (mode == 0u) {
        daq_list[d].running = 0u;
    } else if (mode == 1u) {
        daq_list[d].running = 1u;
        daq_list[d].countdown = 0u;
    } else {
        daq_list[d].selected = 1u;
    }
    xcp_reply[1] = daq_list[d].first_pid;
    return xcp_ok(1u);
}

static uint32_t daq_start_stop_synch(const uint8_t *cto)
{
    const uint32_t mode = cto[1];
    uint32_t d;
    if (mode > 2u) return xcp_error(XCP_ERR_MODE_NOT_VALID);
    if (mode == 1u && !daq_complete(-1)) return xcp_error(XCP_ERR_DAQ_CONFIG);
    for (d = 0u; d < daq_lists; d++) {                      /* wcet-loop: XCP_MAX_DAQ_LISTS */
        if (mode == 0u) {
            daq_list[d].running = 0u;
        } else if (daq_list[d].selected) {
            daq_list[d].running = (uint8_t)(mode == 1u);
            daq_list[d].countdown = 0u;
        }
        if (mode != 0u) daq_list[d].selected = 0u;
    }
    return xcp_ok(0u);
}

static void daq_stop_all(void)
{
    uint32_t d;
    for (d = 0u; d < daq_lists; d++) daq_list[d].running = daq_list[d].selected = 0u;   /* wcet-loop: XCP_MAX_DAQ_LISTS */
}

static void daq_free(void)
{
    daq_lists = 0u;
    daq_allocated = 0u;
    daq_have_pointer = 0u;
    daq_stage = DAQ_LISTS;
}

/* ODT `o`'s packet: its number, then its bytes as they are now (out of line: one copy of the loop to bound) */
static __attribute__((noinline)) void daq_packet(uint32_t o, uint8_t *packet)
{
    uint32_t b;
    packet[0] = (uint8_t)o;
    for (b = 0u; b < daq_odt[o].bytes; b++) packet[1u + b] = *daq_odt[o].byte_at[b];   /* wcet-loop: XCP_ODT_PAYLOAD */
}

/* Daq.sample: one packet per ODT of each running list of `event` whose prescaler is due, in ODT order (the lists'
 * order): which lists are due first, then one loop over the ODTs, each packet a loop over its bytes */
static void daq_sample(uint32_t event)
{
    uint8_t due[XCP_MAX_DAQ_LISTS];
    uint32_t d, o;
    for (d = 0u; d < daq_lists; d++) {                      /* wcet-loop: daq_lists */
        due[d] = 0u;
        if (!daq_list[d].running || daq_list[d].event != event) continue;
        if (daq_list[d].countdown) {
            daq_list[d].countdown--;
            continue;
        }
        daq_list[d].countdown = (uint8_t)(daq_list[d].prescaler - 1u);
        due[d] = 1u;
    }
    for (o = 0u; o < daq_odts; o++) {                       /* wcet-loop: daq_odts */
        if (!due[daq_odt[o].owner]) continue;
        xcp_counters.daq_packets++;
        if (daq_queued >= XCP_DAQ_QUEUE) {                  /* a row of several steps: see the top */
            node_out.tx_dropped++;
            continue;
        }
        daq_packet(o, daq_queue[daq_queued].data);
        daq_queue[daq_queued++].dlc = (uint8_t)(1u + daq_odt[o].bytes);
    }
}

/* ------------------------------------------------------------------------------------------------ entry points */
/* XcpSlave._command: the reply to one CTO into xcp_reply (length 0: none) */
static void xcp_dispatch(const uint8_t *cto, uint32_t length)
{
    static const uint8_t min_length[256] = {
        [XCP_CMD_GET_ID] = 2u, [XCP_CMD_SET_MTA] = 8u, [XCP_CMD_UPLOAD] = 2u, [XCP_CMD_SHORT_UPLOAD] = 8u,
        [XCP_CMD_BUILD_CHECKSUM] = 8u, [XCP_CMD_DOWNLOAD] = 2u, [XCP_CMD_SET_DAQ_PTR] = 6u,
        [XCP_CMD_WRITE_DAQ] = 8u, [XCP_CMD_SET_DAQ_LIST_MODE] = 8u, [XCP_CMD_START_STOP_DAQ_LIST] = 4u,
        [XCP_CMD_START_STOP_SYNCH] = 2u, [XCP_CMD_ALLOC_DAQ] = 4u, [XCP_CMD_ALLOC_ODT] = 5u,
        [XCP_CMD_ALLOC_ODT_ENTRY] = 6u};
    uint32_t code;
    xcp_reply_length = 0u;
    if (length == 0u) {
        xcp_error(XCP_ERR_CMD_SYNTAX);
        return;
    }
    code = cto[0];
    if (!xcp_connected && code != XCP_CMD_CONNECT) {
        xcp_counters.ignored++;
        return;
    }
    switch (code) {
    case XCP_CMD_CONNECT: case XCP_CMD_DISCONNECT: case XCP_CMD_GET_STATUS: case XCP_CMD_SYNCH:
    case XCP_CMD_GET_COMM_MODE_INFO: case XCP_CMD_GET_ID: case XCP_CMD_SET_MTA: case XCP_CMD_UPLOAD:
    case XCP_CMD_SHORT_UPLOAD: case XCP_CMD_BUILD_CHECKSUM: case XCP_CMD_DOWNLOAD: case XCP_CMD_SET_DAQ_PTR:
    case XCP_CMD_WRITE_DAQ: case XCP_CMD_SET_DAQ_LIST_MODE: case XCP_CMD_START_STOP_DAQ_LIST:
    case XCP_CMD_START_STOP_SYNCH: case XCP_CMD_GET_DAQ_PROCESSOR_INFO: case XCP_CMD_GET_DAQ_RESOLUTION_INFO:
    case XCP_CMD_FREE_DAQ: case XCP_CMD_ALLOC_DAQ: case XCP_CMD_ALLOC_ODT: case XCP_CMD_ALLOC_ODT_ENTRY:
        break;
    default:
        xcp_error(XCP_ERR_CMD_UNKNOWN);
        return;
    }
    xcp_counters.commands++;
    if (length < (min_length[code] ? min_length[code] : 1u)) {
        xcp_error(XCP_ERR_CMD_SYNTAX);
        return;
    }
    switch (code) {
    case XCP_CMD_CONNECT:
        xcp_connected = 1u;
        xcp_reply[1] = (uint8_t)(XCP_RESOURCE_CAL_PAG | XCP_RESOURCE_DAQ);
        xcp_reply[2] = (uint8_t)XCP_COMM_MODE_BASIC;
        xcp_reply[3] = (uint8_t)XCP_MAX_CTO;
        xcp_reply[4] = (uint8_t)XCP_MAX_DTO;
        xcp_reply[5] = (uint8_t)(XCP_MAX_DTO >> 8);
        xcp_reply[6] = (uint8_t)XCP_PROTOCOL_LAYER_VERSION;
        xcp_reply[7] = (uint8_t)XCP_TRANSPORT_LAYER_VERSION;
        xcp_ok(7u);
        break;
    case XCP_CMD_DISCONNECT:
        daq_stop_all();                                     /* a master that leaves stops its measurement */
        xcp_connected = 0u;
        xcp_ok(0u);
        break;
    case XCP_CMD_GET_STATUS:
        xcp_reply[1] = (uint8_t)(daq_running() ? XCP_SESSION_DAQ_RUNNING : 0u);
        xcp_reply[2] = xcp_reply[3] = xcp_reply[4] = xcp_reply[5] = 0u;
        xcp_ok(5u);
        break;
    case XCP_CMD_SYNCH:
        xcp_error(XCP_ERR_CMD_SYNCH);
        break;
    case XCP_CMD_GET_COMM_MODE_INFO:
        memset(xcp_reply + 1, 0, 6u);
        xcp_reply[7] = (uint8_t)XCP_DRIVER_VERSION;
        xcp_ok(7u);
        break;
    case XCP_CMD_GET_ID: xcp_get_id(cto); break;
    case XCP_CMD_SET_MTA:
        xcp_mta = xcp_u32(cto + 4);
        xcp_ok(0u);
        break;
    case XCP_CMD_UPLOAD: xcp_upload(cto[1], xcp_mta); break;
    case XCP_CMD_SHORT_UPLOAD: xcp_upload(cto[1], xcp_u32(cto + 4)); break;
    case XCP_CMD_DOWNLOAD: xcp_download(cto, length); break;
    case XCP_CMD_BUILD_CHECKSUM: xcp_checksum(cto); break;
    case XCP_CMD_FREE_DAQ:
        daq_free();
        xcp_ok(0u);
        break;
    case XCP_CMD_ALLOC_DAQ: daq_alloc_daq(cto); break;
    case XCP_CMD_ALLOC_ODT: daq_alloc_odt(cto); break;
    case XCP_CMD_ALLOC_ODT_ENTRY: daq_alloc_odt_entry(cto); break;
    case XCP_CMD_SET_DAQ_PTR: daq_set_pointer(cto); break;
    case XCP_CMD_WRITE_DAQ: daq_write(cto); break;
    case XCP_CMD_SET_DAQ_LIST_MODE: daq_set_mode(cto); break;
    case XCP_CMD_START_STOP_DAQ_LIST: daq_start_stop_list(cto); break;
    case XCP_CMD_START_STOP_SYNCH: daq_start_stop_synch(cto); break;
    case XCP_CMD_GET_DAQ_PROCESSOR_INFO:
        xcp_reply[1] = (uint8_t)XCP_DAQ_PROPERTIES;
        xcp_reply[2] = (uint8_t)XCP_MAX_ODT_ENTRIES;
        xcp_reply[3] = (uint8_t)(XCP_MAX_ODT_ENTRIES >> 8);
        xcp_reply[4] = (uint8_t)XCP_EVENTS;
        xcp_reply[5] = (uint8_t)(XCP_EVENTS >> 8);
        xcp_reply[6] = 0u;
        xcp_reply[7] = (uint8_t)XCP_DAQ_KEY_BYTE;
        xcp_ok(7u);
        break;
    default:                                                /* GET_DAQ_RESOLUTION_INFO: bytes, no STIM, no stamps */
        xcp_reply[1] = 1u;
        xcp_reply[2] = (uint8_t)XCP_ODT_PAYLOAD;
        xcp_reply[3] = 1u;
        xcp_reply[4] = xcp_reply[5] = xcp_reply[6] = xcp_reply[7] = 0u;
        xcp_ok(7u);
        break;
    }
}

/* One command frame (node_on_frame routes the XCP command id here, before the DBC's validation): its reply. */
void xcp_command(uint32_t dlc, const uint8_t *data)
{
    struct node_frame *frame;
    xcp_dispatch(data, dlc < 8u ? dlc : 8u);
    if (xcp_reply_length == 0u) return;
    frame = tx_slot();
    if (frame == NULL) return;
    frame->id = XCP_RES_ID;
    frame->dlc = xcp_reply_length;
    memset(frame->data, 0, sizeof frame->data);
    xcp_copy(frame->data, xcp_reply, xcp_reply_length);
}

/* An event channel's DAQ (XcpSlave.event): nothing while disconnected or no list runs; timed with the DWT. */
__attribute__((noinline)) void xcp_event(uint32_t event)
{
    uint32_t started, before;
    if (!xcp_connected || !daq_running()) return;
    started = DWT_CYCCNT;
    before = xcp_counters.daq_packets;
    daq_sample(event);
    if (xcp_counters.daq_packets != before) {
        xcp_counters.samples++;
        xcp_counters.sample_cycles += DWT_CYCCNT - started;
    }
}

/* The sampled DAQ packets after the call's other frames (the room kept for them: NODE_TX_CAPACITY's last
 * XCP_DAQ_QUEUE frames). */
static __attribute__((noinline)) void xcp_flush(void)
{
    uint32_t i;
    for (i = 0u; i < daq_queued; i++) {                     /* wcet-loop: daq_odts */
        struct node_frame *frame = &node_out.tx[node_out.tx_count++];
        frame->id = XCP_RES_ID;
        frame->dlc = daq_queue[i].dlc;
        memset(frame->data, 0, sizeof frame->data);
        xcp_copy(frame->data, daq_queue[i].data, daq_queue[i].dlc);
    }
    daq_queued = 0u;
}

/* Power-on: disconnected, no DAQ configured (the calibration keeps its .data values). */
static void xcp_init(void)
{
    memset(&xcp_counters, 0, sizeof xcp_counters);
    xcp_connected = 0u;
    xcp_mta = 0u;
    daq_lists = daq_allocated = daq_queued = 0u;
    daq_have_pointer = 0u;
    daq_stage = DAQ_FREE;
}
