/* startup.c: vector table and reset handler for the STM32F446RE (and the STM32F405 of qemu's
 * netduinoplus2: same core, same first 82 vectors). RM0390 10.2, Table 38: 16 system exceptions
 * then 97 interrupt lines. */
#include <stdint.h>

extern uint32_t _sidata, _sdata, _edata, _sbss, _ebss, _estack;
int main(void);
void fd_safe_off(void);
void fd_reset_handler(void);
void SysTick_Handler(void);
static void fd_default_handler(void);
static void fd_hard_fault_handler(void);

#define FD_N_VECTORS (16 + 97)

__attribute__((section(".isr_vector"), used))
static void (*const fd_vectors[FD_N_VECTORS])(void) = {
    [0] = (void (*)(void))(&_estack),
    [1] = fd_reset_handler,
    [2] = fd_default_handler,         /* NMI */
    [3] = fd_hard_fault_handler,
    [4] = fd_hard_fault_handler,      /* MemManage */
    [5] = fd_hard_fault_handler,      /* BusFault */
    [6] = fd_hard_fault_handler,      /* UsageFault */
    [11] = fd_default_handler,        /* SVCall */
    [12] = fd_default_handler,        /* DebugMon */
    [14] = fd_default_handler,        /* PendSV */
    [15] = SysTick_Handler,
    [16 ... FD_N_VECTORS - 1] = fd_default_handler,
};

void fd_reset_handler(void)
{
    uint32_t *src = &_sidata;
    uint32_t *dst;
    for (dst = &_sdata; dst < &_edata; ++dst) {
        *dst = *src++;
    }
    for (dst = &_sbss; dst < &_ebss; ++dst) {
        *dst = 0u;
    }
    /* FPU: CP10 and CP11 full access (PM0214 4.6.1), then DSB/ISB before any FP instruction */
    *(volatile uint32_t *)0xE000ED88u |= 0xFu << 20;
    __asm__ volatile ("dsb\n\tisb" ::: "memory");
    (void)main();
    for (;;) {
    }
}

/* Any fault: zero torque, driver off, then wait for the independent watchdog to reset the board. */
static void fd_hard_fault_handler(void)
{
    fd_safe_off();
    for (;;) {
    }
}

static void fd_default_handler(void)
{
    fd_safe_off();
    for (;;) {
    }
}
