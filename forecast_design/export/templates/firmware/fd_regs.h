/* fd_regs.h: STM32F446RE register map for the peripherals this firmware uses, written from the
 * reference manual RM0390 (STM32F446xx, Rev 6) and the Cortex-M4 generic user guide (PM0214).
 * Section numbers below are RM0390's. Every peripheral is a struct of volatile words at its base
 * address; the drivers take a pointer to the struct, so host unit tests pass a fake register
 * file (a struct in RAM) instead of the hardware address. STM32F405 (qemu netduinoplus2) has the
 * same layout and addresses for every block used here. */
#ifndef FD_REGS_H
#define FD_REGS_H

#include <stdint.h>

#define FD_REG volatile uint32_t

/* 6.3 RCC registers (base 0x40023800, memory map 2.2.2) */
typedef struct {
    FD_REG CR;          /* 0x00 clock control (6.3.1) */
    FD_REG PLLCFGR;     /* 0x04 PLL configuration (6.3.2) */
    FD_REG CFGR;        /* 0x08 clock configuration (6.3.3) */
    FD_REG CIR;         /* 0x0C */
    FD_REG AHB1RSTR;    /* 0x10 */
    FD_REG AHB2RSTR;    /* 0x14 */
    FD_REG AHB3RSTR;    /* 0x18 */
    FD_REG RESERVED0;   /* 0x1C */
    FD_REG APB1RSTR;    /* 0x20 */
    FD_REG APB2RSTR;    /* 0x24 */
    FD_REG RESERVED1[2];
    FD_REG AHB1ENR;     /* 0x30 AHB1 enable: GPIOA bit 0, GPIOB bit 1, DMA1 bit 21 (6.3.10) */
    FD_REG AHB2ENR;     /* 0x34 */
    FD_REG AHB3ENR;     /* 0x38 */
    FD_REG RESERVED2;
    FD_REG APB1ENR;     /* 0x40 APB1 enable: TIM2 0, TIM3 1, TIM5 3, USART2 17, PWR 28, DAC 29 (6.3.13) */
    FD_REG APB2ENR;     /* 0x44 */
    FD_REG RESERVED3[2];
    FD_REG AHB1LPENR, AHB2LPENR, AHB3LPENR, RESERVED4, APB1LPENR, APB2LPENR, RESERVED5[2];
    FD_REG BDCR;        /* 0x70 */
    FD_REG CSR;         /* 0x74 control/status: IWDGRSTF bit 29, RMVF bit 24 (6.3.21) */
} fd_rcc_regs;

/* 3.8 Flash interface registers (base 0x40023C00) */
typedef struct {
    FD_REG ACR;         /* 0x00 access control: LATENCY [3:0], PRFTEN 8, ICEN 9, DCEN 10 (3.8.1) */
} fd_flash_regs;

/* 7.4 GPIO registers (GPIOA 0x40020000, GPIOB 0x40020400) */
typedef struct {
    FD_REG MODER;       /* 0x00 2 bits per pin: 00 input, 01 output, 10 alternate, 11 analog (7.4.1) */
    FD_REG OTYPER;      /* 0x04 */
    FD_REG OSPEEDR;     /* 0x08 */
    FD_REG PUPDR;       /* 0x0C */
    FD_REG IDR;         /* 0x10 */
    FD_REG ODR;         /* 0x14 */
    FD_REG BSRR;        /* 0x18 set (bits 0-15) / reset (bits 16-31) (7.4.7) */
    FD_REG LCKR;        /* 0x1C */
    FD_REG AFR[2];      /* 0x20, 0x24 alternate function, 4 bits per pin (7.4.9, 7.4.10) */
} fd_gpio_regs;

/* 18.4 TIM2 to TIM5 registers (TIM2 0x40000000, TIM3 0x40000400, TIM5 0x40000C00). TIM2 and TIM5
 * have 32-bit CNT/ARR/CCRx; TIM3 is 16-bit. */
typedef struct {
    FD_REG CR1;         /* 0x00 CEN bit 0, ARPE bit 7 (18.4.1) */
    FD_REG CR2;         /* 0x04 */
    FD_REG SMCR;        /* 0x08 SMS [2:0]: 011 encoder mode 3, counts on TI1 and TI2 edges (18.4.3) */
    FD_REG DIER;        /* 0x0C */
    FD_REG SR;          /* 0x10 */
    FD_REG EGR;         /* 0x14 UG bit 0 */
    FD_REG CCMR1;       /* 0x18 CC1S [1:0], IC1F [7:4], CC2S [9:8], IC2F [15:12]; OC1M [6:4], OC1PE 3 (18.4.7) */
    FD_REG CCMR2;       /* 0x1C */
    FD_REG CCER;        /* 0x20 CC1E 0, CC1P 1, CC2E 4, CC2P 5 (18.4.9) */
    FD_REG CNT;         /* 0x24 counter (18.4.10) */
    FD_REG PSC;         /* 0x28 prescaler */
    FD_REG ARR;         /* 0x2C auto-reload */
    FD_REG RESERVED0;   /* 0x30 */
    FD_REG CCR1;        /* 0x34 capture/compare 1 */
    FD_REG CCR2;        /* 0x38 */
    FD_REG CCR3;        /* 0x3C */
    FD_REG CCR4;        /* 0x40 */
} fd_tim_regs;

/* 25.6 USART registers (USART2 0x40004400) */
typedef struct {
    FD_REG SR;          /* 0x00 RXNE bit 5, TC 6, TXE 7; ORE 3, FE 1 (25.6.1) */
    FD_REG DR;          /* 0x04 */
    FD_REG BRR;         /* 0x08 mantissa [15:4], fraction [3:0] (25.6.3) */
    FD_REG CR1;         /* 0x0C UE 13, TE 3, RE 2 (25.6.4) */
    FD_REG CR2;         /* 0x10 */
    FD_REG CR3;         /* 0x14 DMAR bit 6, DMAT bit 7 (25.6.6) */
    FD_REG GTPR;        /* 0x18 */
} fd_usart_regs;

/* 9.5 DMA registers (DMA1 0x40026000): LISR/HISR, LIFCR/HIFCR, then 8 streams of 6 words at 0x10 + 0x18 n */
typedef struct {
    FD_REG CR;          /* EN 0, TCIE 4, DIR [7:6], CIRC 8, MINC 10, CHSEL [27:25] (9.5.5) */
    FD_REG NDTR;        /* items left (9.5.6) */
    FD_REG PAR;         /* peripheral address */
    FD_REG M0AR;        /* memory address */
    FD_REG M1AR;
    FD_REG FCR;
} fd_dma_stream_regs;

typedef struct {
    FD_REG LISR;        /* 0x00 streams 0-3 flags */
    FD_REG HISR;        /* 0x04 streams 4-7 flags: stream 6 TCIF bit 21 (9.5.2) */
    FD_REG LIFCR;       /* 0x08 */
    FD_REG HIFCR;       /* 0x0C stream 6 clear bits 16-21 (9.5.4) */
    fd_dma_stream_regs S[8];
} fd_dma_regs;

/* 14.5 DAC registers (0x40007400) */
typedef struct {
    FD_REG CR;          /* EN1 bit 0, BOFF1 bit 1 (14.5.1) */
    FD_REG SWTRIGR;     /* 0x04 */
    FD_REG DHR12R1;     /* 0x08 channel 1 12-bit right aligned data (14.5.3) */
} fd_dac_regs;

/* 19.4 IWDG registers (0x40003000) */
typedef struct {
    FD_REG KR;          /* key: 0xCCCC start, 0xAAAA reload, 0x5555 unlock (19.4.1) */
    FD_REG PR;          /* prescaler: 0 = /4 ... (19.4.2) */
    FD_REG RLR;         /* reload, 12 bits (19.4.3) */
    FD_REG SR;
} fd_iwdg_regs;

/* 5.4 PWR registers (0x40007000): VOS [15:14] (5.4.1) */
typedef struct {
    FD_REG CR;
    FD_REG CSR;
} fd_pwr_regs;

/* PM0214 4.5 SysTick (0xE000E010) */
typedef struct {
    FD_REG CTRL;        /* ENABLE 0, TICKINT 1, CLKSOURCE 2 (processor clock), COUNTFLAG 16 */
    FD_REG LOAD;
    FD_REG VAL;
    FD_REG CALIB;
} fd_systick_regs;

#define FD_RCC     ((fd_rcc_regs *)0x40023800u)
#define FD_FLASH   ((fd_flash_regs *)0x40023C00u)
#define FD_PWR     ((fd_pwr_regs *)0x40007000u)
#define FD_GPIOA   ((fd_gpio_regs *)0x40020000u)
#define FD_GPIOB   ((fd_gpio_regs *)0x40020400u)
#define FD_TIM2    ((fd_tim_regs *)0x40000000u)
#define FD_TIM3    ((fd_tim_regs *)0x40000400u)
#define FD_TIM5    ((fd_tim_regs *)0x40000C00u)
#define FD_USART2  ((fd_usart_regs *)0x40004400u)
#define FD_DMA1    ((fd_dma_regs *)0x40026000u)
#define FD_DAC     ((fd_dac_regs *)0x40007400u)
#define FD_IWDG    ((fd_iwdg_regs *)0x40003000u)
#define FD_SYSTICK ((fd_systick_regs *)0xE000E010u)
#define FD_SCB_ICSR  (*(volatile uint32_t *)0xE000ED04u)  /* PENDSTSET bit 26 (PM0214 4.4.3) */
#define FD_SCB_SHPR3 (*(volatile uint32_t *)0xE000ED20u)  /* SysTick priority [31:24] (PM0214 4.4.8) */
#define FD_SCB_CPACR (*(volatile uint32_t *)0xE000ED88u)  /* CP10/CP11 [23:20] (PM0214 4.6.1) */

#endif /* FD_REGS_H */
