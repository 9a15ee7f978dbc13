/* foc_isr.c - the motor control beside the estimator: a field-oriented current loop as an inverter runs it, in
 * its own periodic interrupt (bench firmware timing).
 *
 * Every control period the PWM timer triggers the phase-current conversion; its end-of-conversion interrupt runs
 * foc_isr: the two sampled phase currents and the rotor angle in, three PWM duty cycles out. The steps, float32 on
 * the FPU:
 *   Clarke      i_alpha = i_a, i_beta = (i_a + 2 i_b) / sqrt 3             (balanced phases: i_c = -i_a - i_b)
 *   Park        i_d = i_alpha cos t + i_beta sin t, i_q = -i_alpha sin t + i_beta cos t
 *   two PI      on i_d* - i_d and i_q* - i_q, with anti-windup by back-calculation: the integrator takes back
 *               what the voltage limit cut off, so it never winds up while the output is saturated;
 *               the limit is the inverter's linear range, |v| <= v_dc / sqrt 3, the d axis first
 *   inverse Park, then space-vector modulation by min-max (zero-sequence) injection, which gives the same
 *               switching times as the sector form of SVM without its sector search, duties clamped to [0, 1].
 * sin and cos of the electrical angle (a 16-bit fraction of a turn, as an encoder or resolver interface gives it)
 * by quadrant reduction and odd/even polynomials (error below 1e-6 of full scale), no libm.
 *
 * The inputs are what a DMA transfer leaves in RAM (foc_adc: raw 12-bit phase-current samples, the angle, the DC
 * link voltage) and the outputs go to foc_pwm, which on the silicon are the timer's three compare registers; the
 * current references are the background's (a torque or speed loop writes them). foc_init sets the discrete
 * gains for a control rate. The interrupt's vector sits in .isr_vector.irq, after the 16 system vectors of
 * startup.c (firmware.ld places it), at FOC_IRQ: the end-of-conversion interrupt of an STM32F4's ADCs (IRQ 18).
 */
#include <stdint.h>

#include "foc_isr.h"

#define FOC_IRQ 18                      /* ADC1/2/3 global interrupt of an STM32F4 */
#define DWT_CYCCNT (*(volatile uint32_t *)0xE0001004u)   /* the cycle counter the node enables */
/* The Cortex-M4's exception entry (stacking, vector fetch) and return (unstacking) with zero wait states, which
 * the handler's own DWT reads cannot see (ARM Cortex-M4 TRM r0p1, 3.3.1 and 5.5.1; docs/firmware.md). */
#define FOC_EXCEPTION_CYCLES (12u + 10u)
#define SQRT3_INV 0.57735026919f        /* 1 / sqrt 3 */
#define TWO_PI 6.28318530718f
#define ADC_MID 2048.0f                 /* the current sensors' zero, in 12-bit counts */
#define AMPS_PER_COUNT 0.1220703125f    /* +-250 A over the converter's range */

/* An illustrative traction motor's d/q inductances and phase resistance: the PI gains give the current loop a
 * 1 kHz bandwidth (k_p = L w_c, k_i = R w_c, pole-zero cancellation). */
#define MOTOR_L_H 0.00025f
#define MOTOR_R_OHM 0.02f
#define LOOP_BANDWIDTH_HZ 1000.0f

struct foc_pi {
    float kp, ki_ts, kaw, integral;     /* proportional gain, integral gain times the period, anti-windup gain */
};

volatile struct foc_adc foc_adc = {2048u, 2048u, 0u, 0u, 400.0f};
volatile struct foc_reference foc_reference = {0.0f, 0.0f};
volatile struct foc_pwm foc_pwm;
volatile uint32_t foc_ticks;
volatile uint32_t foc_busy_cycles;
volatile float foc_rate_hz;
static struct foc_pi pi_d, pi_q;

void foc_init(float rate_hz)
{
    const float kp = MOTOR_L_H * TWO_PI * LOOP_BANDWIDTH_HZ;
    const float ki_ts = MOTOR_R_OHM * TWO_PI * LOOP_BANDWIDTH_HZ / rate_hz;
    pi_d.kp = pi_q.kp = kp;
    pi_d.ki_ts = pi_q.ki_ts = ki_ts;
    pi_d.kaw = pi_q.kaw = ki_ts / kp;
    pi_d.integral = pi_q.integral = 0.0f;
    foc_ticks = 0u;
    foc_busy_cycles = 0u;
    foc_rate_hz = rate_hz;
}

/* sin and cos of a 16-bit fraction of a turn: the quadrant from the top two bits, then polynomials on
 * [0, pi/2) (Taylor to x^9 and x^8: below 4e-6 there). */
static void sin_cos(uint16_t angle, float *s, float *c)
{
    const uint32_t quadrant = (uint32_t)angle >> 14;
    const float x = (float)(angle & 0x3FFFu) * (TWO_PI / 65536.0f);
    const float x2 = x * x;
    const float sx = x * (1.0f - x2 * (1.0f / 6.0f - x2 * (1.0f / 120.0f - x2 * (1.0f / 5040.0f
                     - x2 * (1.0f / 362880.0f)))));
    const float cx = 1.0f - x2 * (0.5f - x2 * (1.0f / 24.0f - x2 * (1.0f / 720.0f - x2 * (1.0f / 40320.0f))));
    switch (quadrant) {
    case 0u: *s = sx; *c = cx; break;
    case 1u: *s = cx; *c = -sx; break;
    case 2u: *s = -sx; *c = -cx; break;
    default: *s = -cx; *c = sx; break;
    }
}

static float clamp(float value, float limit)
{
    if (value > limit) return limit;
    if (value < -limit) return -limit;
    return value;
}

/* u = k_p e + I, limited to +-limit; I += k_i T e + k_aw (u_limited - u): back-calculation anti-windup. */
static float pi_step(struct foc_pi *pi, float error, float limit)
{
    const float wanted = pi->kp * error + pi->integral;
    const float output = clamp(wanted, limit);
    pi->integral += pi->ki_ts * error + pi->kaw * (output - wanted);
    return output;
}

/* A phase's duty cycle: 0.5 is the phase at half the DC link, clamped to what the timer can do. */
static float duty(float phase_voltage, float dc_inverse)
{
    const float d = 0.5f + phase_voltage * dc_inverse;
    if (d > 1.0f) return 1.0f;
    if (d < 0.0f) return 0.0f;
    return d;
}

void foc_isr(void)
{
    const uint32_t entered = DWT_CYCCNT;
    const float i_a = ((float)foc_adc.phase_a - ADC_MID) * AMPS_PER_COUNT;
    const float i_b = ((float)foc_adc.phase_b - ADC_MID) * AMPS_PER_COUNT;
    const float v_dc = foc_adc.v_dc;
    const float v_max = v_dc * SQRT3_INV;
    float s, c, i_alpha, i_beta, i_d, i_q, v_d, v_q, v_alpha, v_beta, v_a, v_b, v_c, high, low, offset, inverse;

    /* Clarke */
    i_alpha = i_a;
    i_beta = (i_a + 2.0f * i_b) * SQRT3_INV;
    /* Park */
    sin_cos(foc_adc.angle, &s, &c);
    i_d = i_alpha * c + i_beta * s;
    i_q = i_beta * c - i_alpha * s;
    /* the two PI controllers, the d axis first within the voltage limit */
    v_d = pi_step(&pi_d, foc_reference.i_d - i_d, v_max);
    v_q = pi_step(&pi_q, foc_reference.i_q - i_q, __builtin_sqrtf(v_max * v_max - v_d * v_d));
    /* inverse Park */
    v_alpha = v_d * c - v_q * s;
    v_beta = v_d * s + v_q * c;
    /* inverse Clarke, then min-max injection: the space vector's centred switching times */
    v_a = v_alpha;
    v_b = -0.5f * v_alpha + 0.866025403784f * v_beta;
    v_c = -0.5f * v_alpha - 0.866025403784f * v_beta;
    high = v_a > v_b ? v_a : v_b;
    high = high > v_c ? high : v_c;
    low = v_a < v_b ? v_a : v_b;
    low = low < v_c ? low : v_c;
    offset = -0.5f * (high + low);
    inverse = v_dc > 1.0f ? 1.0f / v_dc : 1.0f;
    foc_pwm.duty[0] = duty(v_a + offset, inverse);
    foc_pwm.duty[1] = duty(v_b + offset, inverse);
    foc_pwm.duty[2] = duty(v_c + offset, inverse);
    foc_ticks++;
    foc_busy_cycles += DWT_CYCCNT - entered + FOC_EXCEPTION_CYCLES;   /* the CPU load the node reports */
}

/* The IRQ vectors after the 16 system vectors of startup.c: foc_isr at FOC_IRQ, nothing else enabled. */
__attribute__((used, section(".isr_vector.irq"))) void (*const foc_irq_vectors[FOC_IRQ + 1])(void) = {
    [FOC_IRQ] = foc_isr,
};
