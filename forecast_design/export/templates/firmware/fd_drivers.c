/* fd_drivers.c: see fd_drivers.h. Register bits cite RM0390 sections. */
#include "fd_drivers.h"

void fd_encoder_init(fd_tim_regs *tim)
{
    tim->CR1 = 0u;
    tim->SMCR = 3u;                           /* SMS = 011: encoder mode 3 (18.4.3) */
    tim->CCMR1 = (1u << 0) | (1u << 8)        /* CC1S = 01: IC1 on TI1, CC2S = 01: IC2 on TI2 (18.4.7) */
               | (3u << 4) | (3u << 12);      /* IC1F = IC2F = 0011: fCK_INT, N = 8 digital filter */
    tim->CCER = 0u;                           /* CC1P = CC2P = 0: non-inverted (18.4.9) */
    tim->PSC = 0u;
    tim->ARR = 0xFFFFFFFFu;                   /* full 32-bit range: CNT wraps at 2^32 */
    tim->CNT = 0u;
    tim->EGR = 1u;                            /* UG: load PSC/ARR */
    tim->CR1 = 1u;                            /* CEN */
}

void fd_encoder_zero(fd_encoder *e, uint32_t raw)
{
    e->last = raw;
    e->count = 0;
    e->delta = 0;
}

void fd_encoder_update(fd_encoder *e, uint32_t raw)
{
    /* modular difference: correct across the 0xFFFFFFFF <-> 0 wrap in either direction */
    e->delta = (int32_t)(raw - e->last);
    e->last = raw;
    e->count += e->delta;
}

static float fd_unit(float tau, float tau_full_scale)
{
    float x = tau / tau_full_scale;
    if (!(x == x)) {                          /* NaN: zero torque */
        x = 0.0f;
    }
    if (x > 1.0f) {
        x = 1.0f;
    } else if (x < -1.0f) {
        x = -1.0f;
    }
    return x;
}

uint32_t fd_dac_code(float tau, float tau_full_scale)
{
    /* code = 2047.5 (1 + x) rounded: -fs -> 0, 0 -> 2048 (the nearer of 2047/2048 is chosen by
     * round-half-up), +fs -> 4095 */
    const float code = 2047.5f * (1.0f + fd_unit(tau, tau_full_scale)) + 0.5f;
    uint32_t c = (uint32_t)code;
    return c > 4095u ? 4095u : c;
}

uint32_t fd_pwm_compare(float tau, float tau_full_scale, uint32_t arr)
{
    /* duty = 0.5 + 0.4 x in [0.1, 0.9] of the period (ARR + 1 counts) */
    const float duty = 0.5f + 0.4f * fd_unit(tau, tau_full_scale);
    return (uint32_t)(duty * (float)(arr + 1u) + 0.5f);
}

void fd_dac_init(fd_dac_regs *dac)
{
    dac->DHR12R1 = 2048u;                     /* mid-scale: zero torque before the output is enabled */
    dac->CR = 1u;                             /* EN1, output buffer on (BOFF1 = 0) (14.5.1) */
}

void fd_dac_write(fd_dac_regs *dac, uint32_t code)
{
    dac->DHR12R1 = code & 0xFFFu;
}

void fd_pwm_init(fd_tim_regs *tim, uint32_t psc, uint32_t arr)
{
    tim->CR1 = 0u;
    tim->PSC = psc;
    tim->ARR = arr;
    tim->CCR1 = (arr + 1u) / 2u;              /* 50 %: zero torque */
    tim->CCMR1 = (6u << 4) | (1u << 3);       /* OC1M = 110 PWM mode 1, OC1PE preload (18.4.7) */
    tim->CCER = 1u;                           /* CC1E */
    tim->EGR = 1u;
    tim->CR1 = (1u << 7) | 1u;                /* ARPE, CEN */
}

void fd_pwm_write(fd_tim_regs *tim, uint32_t compare)
{
    tim->CCR1 = compare;
}

void fd_gpio_mode(fd_gpio_regs *g, unsigned pin, unsigned mode, unsigned af)
{
    g->MODER = (g->MODER & ~(3u << (2u * pin))) | ((mode & 3u) << (2u * pin));
    g->OSPEEDR |= 2u << (2u * pin);           /* fast */
    g->AFR[pin >> 3] = (g->AFR[pin >> 3] & ~(0xFu << (4u * (pin & 7u)))) | ((af & 0xFu) << (4u * (pin & 7u)));
}

void fd_gpio_write(fd_gpio_regs *g, unsigned pin, int high)
{
    g->BSRR = high ? (1u << pin) : (1u << (pin + 16u));
}

uint32_t fd_usart_brr(uint32_t pclk_hz, uint32_t baud)
{
    /* oversampling by 16: USARTDIV = pclk / (16 baud) as 12.4 fixed point, rounded (25.4.4) */
    return (pclk_hz + baud / 2u) / baud;
}

void fd_uart_init(fd_uart *u, fd_usart_regs *usart, fd_dma_regs *dma, uint32_t pclk_hz, uint32_t baud)
{
    u->usart = usart;
    u->dma = dma;
    u->rx_tail = u->rx_head = 0u;
    u->tx_head = u->tx_tail = 0u;
    u->tx_busy = 0u;
    u->tx_dropped = 0u;
    usart->CR1 = 0u;
    usart->BRR = fd_usart_brr(pclk_hz, baud);
    if (dma != 0) {
        fd_dma_stream_regs *rx = &dma->S[5];
        usart->CR3 = (1u << 6) | (1u << 7);   /* DMAR, DMAT (25.6.6) */
        rx->CR = 0u;
        rx->PAR = (uint32_t)(uintptr_t)&usart->DR;
        rx->M0AR = (uint32_t)(uintptr_t)u->rx;
        rx->NDTR = FD_RX_SIZE;
        rx->CR = (4u << 25) | (1u << 10) | (1u << 8);  /* CHSEL 4, MINC, CIRC, periph-to-memory */
        rx->CR |= 1u;                          /* EN */
    }
    usart->CR1 = (1u << 13) | (1u << 3) | (1u << 2);   /* UE, TE, RE */
}

static uint32_t fd_rx_head(fd_uart *u)
{
    if (u->dma != 0) {
        return (FD_RX_SIZE - u->dma->S[5].NDTR) % FD_RX_SIZE;
    }
    while (u->usart->SR & (1u << 5)) {         /* RXNE: drain the data register into the ring */
        u->rx[u->rx_head] = (uint8_t)u->usart->DR;
        u->rx_head = (u->rx_head + 1u) % FD_RX_SIZE;
    }
    return u->rx_head;
}

int fd_uart_getc(fd_uart *u)
{
    int c;
    if (u->rx_tail == fd_rx_head(u)) {
        return -1;
    }
    c = u->rx[u->rx_tail];
    u->rx_tail = (u->rx_tail + 1u) % FD_RX_SIZE;
    return c;
}

int fd_uart_put(fd_uart *u, const uint8_t *p, uint32_t n)
{
    uint32_t used = (u->tx_head - u->tx_tail) % FD_TX_SIZE;
    uint32_t i;
    if (used + n >= FD_TX_SIZE) {
        u->tx_dropped += n;
        return -1;
    }
    for (i = 0u; i < n; ++i) {
        u->tx[(u->tx_head + i) % FD_TX_SIZE] = p[i];
    }
    u->tx_head = (u->tx_head + n) % FD_TX_SIZE;
    return 0;
}

void fd_uart_kick(fd_uart *u)
{
    if (u->dma == 0) {
        while (u->tx_tail != u->tx_head && (u->usart->SR & (1u << 7))) {   /* TXE */
            u->usart->DR = u->tx[u->tx_tail];
            u->tx_tail = (u->tx_tail + 1u) % FD_TX_SIZE;
        }
        return;
    }
    {
        fd_dma_stream_regs *tx = &u->dma->S[6];
        uint32_t head, n;
        if (u->tx_busy != 0u) {
            if (tx->CR & 1u) {
                return;                        /* chunk still in flight */
            }
            u->tx_tail = (u->tx_tail + u->tx_busy) % FD_TX_SIZE;
            u->tx_busy = 0u;
        }
        head = u->tx_head;
        if (head == u->tx_tail) {
            return;
        }
        n = head > u->tx_tail ? head - u->tx_tail : FD_TX_SIZE - u->tx_tail;   /* contiguous part */
        u->dma->HIFCR = 0x3Du << 16;           /* clear stream 6 flags (9.5.4) */
        tx->PAR = (uint32_t)(uintptr_t)&u->usart->DR;
        tx->M0AR = (uint32_t)(uintptr_t)&u->tx[u->tx_tail];
        tx->NDTR = n;
        tx->CR = (4u << 25) | (1u << 10) | (1u << 6);  /* CHSEL 4, MINC, memory-to-peripheral */
        u->tx_busy = n;
        tx->CR |= 1u;                          /* EN; the stream clears EN itself at the end */
    }
}
