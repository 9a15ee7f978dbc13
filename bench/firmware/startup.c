/* startup.c - the minimal start-up code that makes the model a flashable Cortex-M4F image (bench firmware build).
 *
 * The vector table sits at the start of flash (0x08000000, firmware.ld): the initial stack pointer, then the
 * reset handler and the core's fault and system handlers. Reset_Handler enables the FPU (the model is all
 * single-precision VFP code), copies .data from flash to RAM, zeroes .bss and idles. An application links the
 * model (fw_model.h) with its own main loop, CAN driver and timer, and calls fw_* from there; the bench's
 * emulator calls fw_* directly, without running this file's code.
 */

/* Provided by firmware.ld. */
extern unsigned int _estack, _sidata, _sdata, _edata, _sbss, _ebss;

void Reset_Handler(void);

/* Any exception the image does not expect: stop here (a debugger shows where). */
static void Default_Handler(void)
{
    for (;;) {
    }
}

/* The Armv7-M vector table: initial SP, then the 15 system exceptions (0 = reserved). */
struct vector_table {
    const void *initial_sp;
    void (*handler[15])(void);
};

__attribute__((used, section(".isr_vector"))) const struct vector_table fw_vector_table = {
    &_estack,
    {
        Reset_Handler,      /* Reset */
        Default_Handler,    /* NMI */
        Default_Handler,    /* HardFault */
        Default_Handler,    /* MemManage */
        Default_Handler,    /* BusFault */
        Default_Handler,    /* UsageFault */
        0, 0, 0, 0,         /* reserved */
        Default_Handler,    /* SVCall */
        Default_Handler,    /* DebugMonitor */
        0,                  /* reserved */
        Default_Handler,    /* PendSV */
        Default_Handler,    /* SysTick */
    },
};

void Reset_Handler(void)
{
    /* CPACR (0xE000ED88): full access to CP10 and CP11, the FPU, before any floating-point instruction */
    volatile unsigned int *const cpacr = (volatile unsigned int *)0xE000ED88u;
    const unsigned int *src = &_sidata;
    unsigned int *dst;
    *cpacr |= 0xFu << 20;
    __asm__ volatile("dsb\n\tisb" ::: "memory");
    for (dst = &_sdata; dst < &_edata;) *dst++ = *src++;    /* .data: initial values from flash */
    for (dst = &_sbss; dst < &_ebss;) *dst++ = 0u;           /* .bss: zero */
    for (;;) {
        __asm__ volatile("wfi");                               /* the application's main loop goes here */
    }
}
