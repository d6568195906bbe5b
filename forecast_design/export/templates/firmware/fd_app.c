/* fd_app.c: the force-control firmware. Board build: a 2 kHz SysTick interrupt reads the encoders,
 * runs fd_step and writes the torque command; the main loop serves the protocol. PIL build
 * (FD_PIL = 1): each SENSOR frame from the host carries the raw encoder counts of one period and
 * the same period code answers with its SAMPLE, instead of timers and DAC/PWM.
 *
 * Safety: the torque is zero and the ESCON disabled until START; any fault (host silent for the
 * link timeout, garbage beyond resynchronisation, a dropped SENSOR frame, a period overrun, an
 * implausible encoder jump, a controller output that is NaN or infinite) zeroes the torque, disables the driver and reports FAULT, STATS and
 * DONE (reason 2). The independent watchdog resets a hung board; the next START reports it. */
#include <stdint.h>
#include "fd_config.h"
#include "fd_controller.h"
#include "fd_drivers.h"
#include "fd_protocol.h"
#include "fd_regs.h"
#include "fd_reference.h"

#define FD_CALIB_LOOPS 10000u   /* calibration loop: 2 instructions per iteration (subs, bne) */

static fd_uart fd_link;
static fd_parser fd_rx;
static fd_state fd_ctrl;
static fd_encoder fd_enc_m;
static fd_encoder fd_enc_e;
static fd_reference fd_ref;

static volatile uint32_t fd_ticks;          /* SysTick periods since boot */
static volatile uint32_t fd_last_host;      /* fd_ticks at the last intact host frame */
static volatile uint32_t fd_running;        /* 1 during a run */
static uint32_t fd_requested;               /* samples requested at START */
static uint32_t fd_index;                   /* next sample index */
static uint16_t fd_seq;                     /* board frame sequence */
static uint32_t fd_have_controller;
static float fd_tau_limit = FD_TAU_LIMIT;   /* min(compiled limit, uploaded tau_max) */
static uint32_t fd_watchdog_reset;          /* the last reset came from the IWDG */

static uint32_t fd_stat_steps;
static uint32_t fd_stat_max;
static uint64_t fd_stat_sum;
static uint32_t fd_stat_calib;

static uint32_t fd_irq_save(void)
{
    uint32_t primask;
    __asm__ volatile ("mrs %0, primask\n\tcpsid i" : "=r"(primask) :: "memory");
    return primask;
}

static void fd_irq_restore(uint32_t primask)
{
    __asm__ volatile ("msr primask, %0" :: "r"(primask) : "memory");
}

static uint32_t fd_elapsed(uint32_t t0, uint32_t t1)
{
    /* SysTick counts down from FD_SYSTICK_LOAD to 0; at most one reload in between */
    return t0 >= t1 ? t0 - t1 : t0 + FD_SYSTICK_LOAD + 1u - t1;
}

static void fd_send(uint8_t type, const uint8_t *payload, uint32_t n)
{
    uint8_t frame[FD_HEADER_SIZE + 40u + 2u];
    const uint32_t primask = fd_irq_save();
    const uint32_t size = fd_encode_frame(frame, type, fd_seq, payload, n);
    fd_seq = (uint16_t)(fd_seq + 1u);
    (void)fd_uart_put(&fd_link, frame, size);
    fd_irq_restore(primask);
}

static void fd_ack(uint8_t type, uint16_t seq, uint8_t status)
{
    uint8_t p[4];
    p[0] = type;
    fd_put_u16(p + 1, seq);
    p[3] = status;
    fd_send(FD_MSG_ACK, p, 4u);
}

/* The torque output stage: zero torque and driver enable. */
static void fd_output(float tau)
{
#if FD_PIL
    (void)tau;
#elif FD_OUTPUT_PWM
    fd_pwm_write(FD_TIM3, fd_pwm_compare(tau, FD_TAU_FULL_SCALE, FD_PWM_ARR));
#else
    fd_dac_write(FD_DAC, fd_dac_code(tau, FD_TAU_FULL_SCALE));
#endif
}

static void fd_driver_enable(int on)
{
#if FD_PIL
    (void)on;
#else
    fd_gpio_write(FD_GPIOA, FD_PIN_ENABLE, on);
    fd_gpio_write(FD_GPIOA, FD_PIN_LED, on);
#endif
}

/* Called from the HardFault handler as well: no state, no protocol. */
void fd_safe_off(void)
{
    fd_output(0.0f);
    fd_driver_enable(0);
}

static void fd_end_run(uint8_t reason)
{
    uint8_t p[24];
    const float mean = fd_stat_steps ? (float)fd_stat_sum / (float)fd_stat_steps : 0.0f;
    fd_running = 0u;
    fd_safe_off();
    fd_put_u32(p, fd_stat_steps);
    fd_put_u32(p + 4, fd_stat_max);
    fd_put_f32(p + 8, mean);
    fd_put_u32(p + 12, fd_stat_calib);
    fd_put_f32(p + 16, (float)FD_CORE_HZ);
    fd_put_u32(p + 20, 2u * FD_CALIB_LOOPS);
    fd_send(FD_MSG_STATS, p, 24u);
    fd_put_u32(p, fd_index);
    p[4] = reason;
    fd_send(FD_MSG_DONE, p, 5u);
}

static void fd_fault(uint8_t code)
{
    uint8_t p[5];
    fd_safe_off();
    if (!fd_running) {
        return;
    }
    fd_running = 0u;
    fd_put_u32(p, fd_index);
    p[4] = code;
    fd_send(FD_MSG_FAULT, p, 5u);
    fd_end_run(2u);
}

static int32_t fd_abs32(int32_t v)
{
    return v < 0 ? -v : v;
}

/* One control period: encoders -> tau_s = k (theta - q) -> fd_step -> torque -> SAMPLE. */
static void fd_period(uint32_t raw_m, uint32_t raw_e)
{
    const uint32_t t0 = FD_SYSTICK->VAL;
    const uint32_t k = fd_index;
    uint8_t p[36];
    float theta, q, tau_s, tau_r, tau_m, unsat;
    uint32_t dt;
    if (k == 0u) {                               /* angles count from the first period of a run */
        fd_encoder_zero(&fd_enc_m, raw_m);
        fd_encoder_zero(&fd_enc_e, raw_e);
    }
    fd_encoder_update(&fd_enc_m, raw_m);
    fd_encoder_update(&fd_enc_e, raw_e);
    if (fd_abs32(fd_enc_m.delta) > FD_ENCODER_JUMP_LIMIT || fd_abs32(fd_enc_e.delta) > FD_ENCODER_JUMP_LIMIT) {
        fd_fault(FD_FAULT_ENCODER);
        return;
    }
    theta = (float)fd_enc_m.count * FD_RAD_PER_COUNT;
#if FD_LOCKED
    q = 0.0f;
    tau_s = (float)fd_enc_m.count * FD_K_RAD_PER_COUNT;
#else
    q = (float)fd_enc_e.count * FD_RAD_PER_COUNT;
    tau_s = (float)(fd_enc_m.count - fd_enc_e.count) * FD_K_RAD_PER_COUNT;   /* k (theta - q) [N m] */
#endif
    tau_r = fd_reference_value(&fd_ref, k);
    tau_m = fd_step(&fd_ctrl, tau_r, tau_s, theta, q);
    unsat = fd_ctrl.u + fd_ctrl.hat;             /* the command before fd_step's saturation */
    if (!(unsat - unsat == 0.0f)) {              /* NaN or infinite (saturation would hide it): failed */
        fd_fault(FD_FAULT_CONTROLLER);
        return;
    }
    if (tau_m > fd_tau_limit) {                  /* torque limit (fd_step saturates at FD_TAU_LIMIT too) */
        tau_m = fd_tau_limit;
    } else if (tau_m < -fd_tau_limit) {
        tau_m = -fd_tau_limit;
    }
    fd_output(tau_m);
    fd_put_u32(p, k);
    fd_put_f32(p + 4, (float)k * (1.0f / (float)FD_RATE_HZ_U));
    fd_put_f32(p + 8, tau_m);
    fd_put_f32(p + 12, theta);
    fd_put_f32(p + 16, q);
    fd_put_f32(p + 20, tau_s);
    fd_put_f32(p + 24, tau_r);
    fd_put_f32(p + 28, fd_ctrl.u);
    fd_put_f32(p + 32, fd_ctrl.hat);
    fd_send(FD_MSG_SAMPLE, p, 36u);
    fd_index = k + 1u;
    dt = fd_elapsed(t0, FD_SYSTICK->VAL);
    fd_stat_steps++;
    fd_stat_sum += dt;
    if (dt > fd_stat_max) {
        fd_stat_max = dt;
    }
    if (fd_index >= fd_requested) {
        fd_end_run(0u);
    }
}

void SysTick_Handler(void)
{
    fd_ticks++;
    if (fd_running) {
        if (fd_ticks - fd_last_host > FD_LINK_TIMEOUT_TICKS) {
            fd_fault(FD_FAULT_LINK_TIMEOUT);
        }
#if !FD_PIL
        else {
            fd_period(FD_TIM2->CNT, FD_TIM5->CNT);
            if (fd_running && (FD_SCB_ICSR & (1u << 26))) {   /* PENDSTSET: the next tick is already due */
                fd_fault(FD_FAULT_OVERRUN);
            }
        }
        fd_uart_kick(&fd_link);
#endif
    }
}

static int fd_blob_matches(const uint8_t *p, uint32_t n)
{
    uint32_t i;
    if (n != FD_BLOB_SIZE) {
        return 0;
    }
    for (i = 0u; i < n; ++i) {
        if ((i < 8u || i >= 12u) && p[i] != fd_blob[i]) {   /* bytes 8..11: tau_max, may differ */
            return 0;
        }
    }
    return 1;
}

static void fd_start(uint32_t n)
{
    uint32_t primask;
    if (fd_watchdog_reset) {                     /* report the watchdog reset once, as a fault */
        uint8_t p[5];
        fd_watchdog_reset = 0u;
        fd_index = 0u;
        fd_put_u32(p, 0u);
        p[4] = FD_FAULT_WATCHDOG_RESET;
        fd_send(FD_MSG_FAULT, p, 5u);
        fd_end_run(2u);
        return;
    }
    fd_init(&fd_ctrl);
    fd_stat_steps = 0u;
    fd_stat_max = 0u;
    fd_stat_sum = 0u;
    primask = fd_irq_save();
    fd_index = 0u;
    fd_requested = n;
    fd_last_host = fd_ticks;
    fd_output(0.0f);
    fd_driver_enable(1);
    fd_running = 1u;
    fd_irq_restore(primask);
}

static void fd_handle(void)
{
    const uint8_t *p = fd_rx.payload;
    const uint32_t n = fd_rx.length;
    fd_last_host = fd_ticks;
    switch (fd_rx.type) {
    case FD_MSG_PING: {
        uint8_t info[9];
        info[0] = FD_PROTOCOL_VERSION;
        fd_put_f32(info + 1, (float)FD_RATE_HZ_U);
        fd_put_u32(info + 5, FD_MAX_PAYLOAD);
        fd_send(FD_MSG_INFO, info, 9u);
        break;
    }
    case FD_MSG_HEARTBEAT:
        break;
    case FD_MSG_UPLOAD:
        if (fd_running) {
            fd_ack(fd_rx.type, fd_rx.seq, FD_ACK_BUSY);
        } else if (fd_blob_matches(p, n)) {
            const float lim = fd_get_f32(p + 8);
            fd_tau_limit = (lim > 0.0f && lim < FD_TAU_LIMIT) ? lim : FD_TAU_LIMIT;
            fd_have_controller = 1u;
            fd_ack(fd_rx.type, fd_rx.seq, FD_ACK_OK);
        } else {                                 /* not the controller this firmware was built with */
            fd_ack(fd_rx.type, fd_rx.seq, FD_ACK_BAD_PAYLOAD);
        }
        break;
    case FD_MSG_SET_REFERENCE:
        if (fd_running) {
            fd_ack(fd_rx.type, fd_rx.seq, FD_ACK_BUSY);
        } else {
            fd_ack(fd_rx.type, fd_rx.seq, fd_reference_set(&fd_ref, p[0], fd_get_f32(p + 1), fd_get_f32(p + 5),
                                                           fd_get_f32(p + 9), (float)FD_RATE_HZ_U)
                                          ? FD_ACK_OK : FD_ACK_BAD_PAYLOAD);
        }
        break;
    case FD_MSG_START: {
        const uint32_t count = fd_get_u32(p);
        if (fd_running) {
            fd_ack(fd_rx.type, fd_rx.seq, FD_ACK_BUSY);
        } else if (!fd_have_controller) {
            fd_ack(fd_rx.type, fd_rx.seq, FD_ACK_NO_CONTROLLER);
        } else if (count == 0u) {
            fd_ack(fd_rx.type, fd_rx.seq, FD_ACK_BAD_PAYLOAD);
        } else {
            fd_ack(fd_rx.type, fd_rx.seq, FD_ACK_OK);
            fd_start(count);
        }
        break;
    }
    case FD_MSG_STOP:
        fd_ack(fd_rx.type, fd_rx.seq, FD_ACK_OK);
        if (fd_running) {
            fd_end_run(1u);
        }
        break;
#if FD_PIL
    case FD_MSG_SENSOR:
        if (fd_running) {
            if (fd_get_u32(p) != fd_index) {     /* a SENSOR frame went missing (or repeated) */
                fd_fault(FD_FAULT_FRAME_DROPPED);
            } else {
                fd_period(fd_get_u32(p + 4), fd_get_u32(p + 8));
            }
        }
        break;
#endif
    default:
        fd_ack(fd_rx.type, fd_rx.seq, FD_ACK_UNKNOWN_TYPE);
        break;
    }
}

static uint32_t fd_calibrate(void)
{
    uint32_t n = FD_CALIB_LOOPS;
    const uint32_t t0 = FD_SYSTICK->VAL;
    __asm__ volatile ("1: subs %0, %0, #1\n\tbne 1b" : "+r"(n) :: "cc");
    return fd_elapsed(t0, FD_SYSTICK->VAL);
}

#if !FD_PIL
static void fd_clock_init(void)
{
    /* HSI 16 MHz -> PLL: M = 16, N = 336, P = 2 -> 168 MHz SYSCLK, Q = 7 -> 48 MHz (6.3.2);
     * AHB /1, APB1 /4 = 42 MHz (timers 84 MHz), APB2 /2 = 84 MHz (6.3.3); flash 5 wait states
     * at 168 MHz and 3.3 V (3.4.1, Table 5), prefetch and caches on. */
    FD_RCC->APB1ENR |= 1u << 28;                 /* PWR */
    FD_PWR->CR |= 3u << 14;                      /* VOS scale 1 */
    FD_FLASH->ACR = 5u | (1u << 8) | (1u << 9) | (1u << 10);
    FD_RCC->PLLCFGR = 16u | (336u << 6) | (0u << 16) | (0u << 22) | (7u << 24);   /* P = 2: PLLP = 00, src HSI */
    FD_RCC->CR |= 1u << 24;                      /* PLLON */
    while (!(FD_RCC->CR & (1u << 25))) {         /* PLLRDY */
    }
    FD_RCC->CFGR = (5u << 10) | (4u << 13) | 2u; /* PPRE1 = /4, PPRE2 = /2, SW = PLL */
    while (((FD_RCC->CFGR >> 2) & 3u) != 2u) {   /* SWS = PLL */
    }
}

static void fd_board_init(void)
{
    FD_RCC->AHB1ENR |= (1u << 0) | (1u << 1) | (1u << 21);               /* GPIOA, GPIOB, DMA1 */
    FD_RCC->APB1ENR |= (1u << 0) | (1u << 1) | (1u << 3) | (1u << 17) | (1u << 29);  /* TIM2/3/5, USART2, DAC */
    fd_gpio_mode(FD_GPIOA, 2u, 2u, 7u);          /* PA2 USART2_TX, AF7 */
    fd_gpio_mode(FD_GPIOA, 3u, 2u, 7u);          /* PA3 USART2_RX, AF7 */
    fd_gpio_mode(FD_GPIOA, 15u, 2u, 1u);         /* PA15 TIM2_CH1, AF1: motor encoder A */
    fd_gpio_mode(FD_GPIOB, 3u, 2u, 1u);          /* PB3 TIM2_CH2, AF1: motor encoder B */
    fd_gpio_mode(FD_GPIOA, 0u, 2u, 2u);          /* PA0 TIM5_CH1, AF2: environment encoder A */
    fd_gpio_mode(FD_GPIOA, 1u, 2u, 2u);          /* PA1 TIM5_CH2, AF2: environment encoder B */
    fd_gpio_mode(FD_GPIOA, FD_PIN_ENABLE, 1u, 0u);   /* ESCON enable, output */
    fd_gpio_mode(FD_GPIOA, FD_PIN_LED, 1u, 0u);      /* LD2 */
    fd_driver_enable(0);
#if FD_OUTPUT_PWM
    fd_gpio_mode(FD_GPIOA, 6u, 2u, 2u);          /* PA6 TIM3_CH1, AF2: ESCON PWM set value */
    fd_pwm_init(FD_TIM3, 0u, FD_PWM_ARR);
#else
    fd_gpio_mode(FD_GPIOA, 4u, 3u, 0u);          /* PA4 DAC_OUT1, analog: ESCON analog set value */
    fd_dac_init(FD_DAC);
#endif
    fd_encoder_init(FD_TIM2);
    fd_encoder_init(FD_TIM5);
}
#endif

int main(void)
{
    uint32_t seen = 0u;
    fd_watchdog_reset = (FD_RCC->CSR >> 29) & 1u;    /* IWDGRSTF (6.3.21) */
    FD_RCC->CSR |= 1u << 24;                          /* RMVF: clear the reset flags */
#if !FD_PIL
    fd_clock_init();
    fd_board_init();
    fd_uart_init(&fd_link, FD_USART2, FD_DMA1, FD_PCLK1_HZ, FD_BAUD);
#else
    fd_uart_init(&fd_link, FD_USART2, 0, FD_PCLK1_HZ, FD_BAUD);
#endif
    fd_parser_init(&fd_rx);
    fd_reference_set(&fd_ref, 0u, 0.0f, 0.0f, 0.0f, (float)FD_RATE_HZ_U);
    FD_SYSTICK->LOAD = FD_SYSTICK_LOAD;
    FD_SYSTICK->VAL = 0u;
    FD_SYSTICK->CTRL = 5u;                       /* processor clock, enabled, no interrupt yet */
    fd_stat_calib = fd_calibrate();
    FD_SCB_SHPR3 = (FD_SCB_SHPR3 & 0x00FFFFFFu);     /* SysTick: highest configurable priority */
    FD_SYSTICK->CTRL = 7u;                       /* + TICKINT */
    /* IWDG (19.3): LSI 32 kHz / 4 = 8 kHz, reload 80: a 10 ms watchdog, refreshed below only
     * while the control tick advances */
    FD_IWDG->KR = 0xCCCCu;
    FD_IWDG->KR = 0x5555u;
    FD_IWDG->PR = 0u;
    FD_IWDG->RLR = 80u;
    FD_IWDG->KR = 0xAAAAu;
    for (;;) {
        int c;
        while ((c = fd_uart_getc(&fd_link)) >= 0) {
            fd_parser_feed(&fd_rx, (uint8_t)c);
            while (fd_parser_next(&fd_rx)) {
                const uint32_t primask = fd_irq_save();   /* the control tick sees a consistent state */
                fd_handle();
                fd_irq_restore(primask);
            }
            if (fd_running && fd_rx.garbage > FD_GARBAGE_LIMIT) {
                const uint32_t primask = fd_irq_save();
                fd_fault(FD_FAULT_LINK_CORRUPT);
                fd_irq_restore(primask);
            }
        }
        {
            const uint32_t primask = fd_irq_save();
            fd_uart_kick(&fd_link);
            fd_irq_restore(primask);
        }
        if (fd_ticks != seen) {
            seen = fd_ticks;
            FD_IWDG->KR = 0xAAAAu;               /* refresh */
        }
/* no WFI in the PIL build: under qemu -icount an idle (WFI) core lets the virtual clock jump to
         * the next timer deadline, so a host slower than real time would trip the link timeout */
    }
}
