/* foc_isr.h - the field-oriented current loop's interrupt (foc_isr.c): what the background and the DMA share
 * with it. */
#ifndef FOC_ISR_H
#define FOC_ISR_H

#include <stdint.h>

struct foc_adc {                 /* written by the ADC's DMA before the interrupt */
    uint16_t phase_a, phase_b;   /* raw 12-bit phase-current samples (2048: zero current) */
    uint16_t angle;              /* electrical rotor angle, a 16-bit fraction of a turn */
    uint16_t reserved;
    float v_dc;                  /* DC link voltage (V) */
};

struct foc_reference {           /* written by the background (torque or speed loop) */
    float i_d, i_q;              /* current references (A) */
};

struct foc_pwm {                 /* the timer's three compare registers on the silicon */
    float duty[3];
};

extern volatile struct foc_adc foc_adc;
extern volatile struct foc_reference foc_reference;
extern volatile struct foc_pwm foc_pwm;
extern volatile uint32_t foc_ticks;   /* interrupts handled since foc_init */
extern volatile uint32_t foc_busy_cycles;   /* the handler's cycles (DWT) plus exception entry and return, summed */
extern volatile float foc_rate_hz;          /* the interrupt's rate (foc_init's) */

void foc_init(float rate_hz);    /* discrete PI gains for this control rate; integrators cleared */
void foc_isr(void);              /* the interrupt handler */

#endif
