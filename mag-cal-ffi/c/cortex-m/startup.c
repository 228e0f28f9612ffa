/* Minimal start-up for the Cortex-M4F C build under QEMU (mps2-an386, the
 * memory map of link.ld): a vector table, the FPU switched on (the Rust
 * library uses it), .data copied to RAM, then newlib's _start (rdimon:
 * zeroes .bss, sets up semihosting stdio, calls main, exits through
 * semihosting with main's status). */
#include <stdint.h>

extern uint32_t __stack_top, __data_load, __data_start, __data_end;
extern void _start(void);

void Reset_Handler(void) {
    /* CPACR: full access to CP10 and CP11 (the FPU). */
    *(volatile uint32_t *)0xE000ED88 |= 0xFu << 20;
    __asm volatile("dsb\n\tisb");
    for (uint32_t *src = &__data_load, *dst = &__data_start; dst < &__data_end;) *dst++ = *src++;
    _start();
    for (;;) {
    }
}

/* A fault ends the run through semihosting (SYS_EXIT, "run-time error"),
 * so QEMU exits with a failure instead of hanging. */
void Fault_Handler(void) {
    register uint32_t op __asm("r0") = 0x18;
    register uint32_t arg __asm("r1") = 0x20023;
    __asm volatile("bkpt 0xab" : : "r"(op), "r"(arg));
    for (;;) {
    }
}

__attribute__((section(".vectors"), used)) static void (*const vectors[16])(void) = {
    (void (*)(void))&__stack_top, Reset_Handler, Fault_Handler, Fault_Handler,
    Fault_Handler,                Fault_Handler, Fault_Handler,
};
