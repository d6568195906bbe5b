/* fd_drivers.h: encoder timers, torque output (DAC or PWM), UART with DMA, GPIO set-up.
 * Every driver takes its peripheral's register block as a pointer (fd_regs.h), so the host unit
 * tests run the same code against a fake register file. */
#ifndef FD_DRIVERS_H
#define FD_DRIVERS_H

#include <stdint.h>
#include "fd_regs.h"

/* --- quadrature encoders on 32-bit timers ------------------------------------------------
 * TIM2 and TIM5 count in encoder mode 3 (RM0390 18.3.16): every edge of both channels, i.e. x4
 * decoding, up or down with the direction. CNT is a free-running 32-bit register that wraps
 * from 0xFFFFFFFF to 0 (and back). The driver keeps the last raw value and adds the signed
 * difference (int32_t)(raw - last) to a 64-bit count: exact as long as the shaft moves less
 * than 2^31 counts (1073 revolutions at 2,000,000 counts/rev) between two reads, i.e. always at
 * 2 kHz, and the 64-bit count itself does not wrap in any run. */
typedef struct {
    uint32_t last;   /* raw CNT at the previous read */
    int64_t count;   /* accumulated counts since fd_encoder_zero */
    int32_t delta;   /* counts moved at the last update */
} fd_encoder;

void fd_encoder_init(fd_tim_regs *tim);
void fd_encoder_zero(fd_encoder *e, uint32_t raw);
void fd_encoder_update(fd_encoder *e, uint32_t raw);

/* --- torque command to the ESCON 50/5 -------------------------------------------------------
 * The ESCON runs in current control; its set value maps linearly from -tau_full_scale to
 * +tau_full_scale [N m at the output shaft]. DAC: 0 V .. VDDA over codes 0 .. 4095 (RM0390 14.3),
 * mid-scale = zero torque. PWM: 10 % .. 90 % duty (the ESCON's PWM set value range), 50 % = zero.
 * Both saturate at the ends; a NaN command gives zero torque. */
uint32_t fd_dac_code(float tau, float tau_full_scale);
uint32_t fd_pwm_compare(float tau, float tau_full_scale, uint32_t arr);
void fd_dac_init(fd_dac_regs *dac);
void fd_dac_write(fd_dac_regs *dac, uint32_t code);
void fd_pwm_init(fd_tim_regs *tim, uint32_t psc, uint32_t arr);
void fd_pwm_write(fd_tim_regs *tim, uint32_t compare);

/* --- GPIO ----------------------------------------------------------------------------------- */
void fd_gpio_mode(fd_gpio_regs *g, unsigned pin, unsigned mode, unsigned af);
void fd_gpio_write(fd_gpio_regs *g, unsigned pin, int high);

/* --- USART2 ---------------------------------------------------------------------------------
 * 8N1 at FD_BAUD. Reception: DMA1 stream 5 channel 4 (RM0390 Table 28) in circular mode into a
 * ring; the write position is FD_RX_SIZE - NDTR. Transmission: DMA1 stream 6 channel 4 from the
 * tx ring, one contiguous chunk at a time. Without DMA (the PIL build: qemu models no DMA) the
 * main loop polls SR.RXNE / SR.TXE into and out of the same rings (a busy-polling core also keeps
 * qemu's -icount virtual clock tied to executed instructions). */
#define FD_RX_SIZE 512u
#define FD_TX_SIZE 2048u
typedef struct {
    fd_usart_regs *usart;
    fd_dma_regs *dma;          /* NULL: polled */
    uint8_t rx[FD_RX_SIZE];
    uint32_t rx_tail;          /* next byte to read */
    uint32_t rx_head;          /* polled mode: next byte to write */
    uint8_t tx[FD_TX_SIZE];
    volatile uint32_t tx_head; /* next free byte */
    volatile uint32_t tx_tail; /* next byte to send */
    uint32_t tx_busy;          /* DMA mode: bytes of the chunk in flight */
    uint32_t tx_dropped;       /* bytes refused because the ring was full */
} fd_uart;

uint32_t fd_usart_brr(uint32_t pclk_hz, uint32_t baud);
void fd_uart_init(fd_uart *u, fd_usart_regs *usart, fd_dma_regs *dma, uint32_t pclk_hz, uint32_t baud);
int fd_uart_getc(fd_uart *u);                     /* -1 when nothing arrived */
int fd_uart_put(fd_uart *u, const uint8_t *p, uint32_t n); /* 0 ok, -1 ring full (nothing queued) */
void fd_uart_kick(fd_uart *u);                    /* move queued bytes toward the line */

#endif /* FD_DRIVERS_H */
