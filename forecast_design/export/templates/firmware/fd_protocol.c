/* fd_protocol.c: see fd_protocol.h. */
#include "fd_protocol.h"

/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no xor-out), bytewise table */
static const uint16_t fd_crc_table[256] = {
#define FD_C(i) ((uint16_t)(fd_crc_bit(fd_crc_bit(fd_crc_bit(fd_crc_bit(fd_crc_bit(fd_crc_bit(fd_crc_bit(fd_crc_bit((uint32_t)(i) << 8))))))))))
#define fd_crc_bit(c) (((c) & 0x8000u) ? ((((c) << 1) ^ 0x1021u) & 0xFFFFu) : (((c) << 1) & 0xFFFFu))
#define FD_C4(i) FD_C(i), FD_C((i) + 1), FD_C((i) + 2), FD_C((i) + 3)
#define FD_C16(i) FD_C4(i), FD_C4((i) + 4), FD_C4((i) + 8), FD_C4((i) + 12)
#define FD_C64(i) FD_C16(i), FD_C16((i) + 16), FD_C16((i) + 32), FD_C16((i) + 48)
    FD_C64(0), FD_C64(64), FD_C64(128), FD_C64(192)
#undef FD_C64
#undef FD_C16
#undef FD_C4
#undef fd_crc_bit
#undef FD_C
};

uint16_t fd_crc16(const uint8_t *p, uint32_t n, uint16_t crc)
{
    uint32_t i;
    for (i = 0u; i < n; ++i) {
        crc = (uint16_t)((crc << 8) ^ fd_crc_table[((crc >> 8) ^ p[i]) & 0xFFu]);
    }
    return crc;
}

void fd_put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

void fd_put_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
}

void fd_put_f32(uint8_t *p, float v)
{
    union { float f; uint32_t u; } b;
    b.f = v;
    fd_put_u32(p, b.u);
}

uint32_t fd_get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

float fd_get_f32(const uint8_t *p)
{
    union { float f; uint32_t u; } b;
    b.u = fd_get_u32(p);
    return b.f;
}

uint32_t fd_encode_frame(uint8_t *out, uint8_t type, uint16_t seq, const uint8_t *payload, uint32_t n)
{
    uint32_t i;
    out[0] = 0xA5u;
    out[1] = 0x5Au;
    fd_put_u16(out + 2, (uint16_t)n);
    out[4] = type;
    fd_put_u16(out + 5, seq);
    for (i = 0u; i < n; ++i) {
        out[FD_HEADER_SIZE + i] = payload[i];
    }
    fd_put_u16(out + FD_HEADER_SIZE + n, fd_crc16(out + 2, 5u + n, 0xFFFFu));
    return FD_HEADER_SIZE + n + 2u;
}

/* payload length of a host-bound type: -1 variable (UPLOAD), -2 not a host type */
static int fd_host_length(uint8_t type)
{
    switch (type) {
    case FD_MSG_PING: case FD_MSG_STOP: case FD_MSG_HEARTBEAT: return 0;
    case FD_MSG_UPLOAD: return -1;
    case FD_MSG_SET_REFERENCE: return 13;
    case FD_MSG_START: return 4;
    case FD_MSG_SENSOR: return 12;
    default: return -2;
    }
}

void fd_parser_init(fd_parser *p)
{
    p->len = 0u;
    p->garbage = 0u;
    p->corrupt = 0u;
    p->frames = 0u;
    p->payload = 0;
}

static void fd_skip(fd_parser *p, uint32_t n)
{
    uint32_t i;
    for (i = n; i < p->len; ++i) {
        p->buf[i - n] = p->buf[i];
    }
    p->len -= n;
    p->garbage += n;
}

/* Try to resolve the buffer: 1 frame found (consumed on the next call), 0 need more bytes. */
static int fd_parser_scan(fd_parser *p)
{
    for (;;) {
        uint32_t n;
        int fixed;
        if (p->len == 0u) {
            return 0;
        }
        if (p->buf[0] != 0xA5u || (p->len >= 2u && p->buf[1] != 0x5Au)) {
            fd_skip(p, 1u);
            continue;
        }
        if (p->len < FD_HEADER_SIZE) {
            return 0;
        }
        n = (uint32_t)p->buf[2] | ((uint32_t)p->buf[3] << 8);
        fixed = fd_host_length(p->buf[4]);
        if (fixed == -2 || n > FD_MAX_PAYLOAD || (fixed >= 0 && n != (uint32_t)fixed)) {
            fd_skip(p, 1u);
            continue;
        }
        if (p->len < FD_HEADER_SIZE + n + 2u) {
            return 0;
        }
        if (fd_crc16(p->buf + 2, 5u + n, 0xFFFFu)
                != ((uint32_t)p->buf[FD_HEADER_SIZE + n] | ((uint32_t)p->buf[FD_HEADER_SIZE + n + 1u] << 8))) {
            p->corrupt++;
            fd_skip(p, 1u);
            continue;
        }
        p->type = p->buf[4];
        p->seq = (uint16_t)((uint32_t)p->buf[5] | ((uint32_t)p->buf[6] << 8));
        p->length = (uint16_t)n;
        p->payload = p->buf + FD_HEADER_SIZE;
        p->frames++;
        p->garbage = 0u;
        return 1;
    }
}

void fd_parser_feed(fd_parser *p, uint8_t byte)
{
    if (p->len < sizeof(p->buf)) {              /* cannot overflow when fd_parser_next runs per byte */
        p->buf[p->len++] = byte;
    }
}

int fd_parser_next(fd_parser *p)
{
    if (p->payload != 0) {                      /* drop the frame delivered by the previous call */
        uint32_t used = FD_HEADER_SIZE + p->length + 2u;
        uint32_t i;
        for (i = used; i < p->len; ++i) {
            p->buf[i - used] = p->buf[i];
        }
        p->len -= used;
        p->payload = 0;
    }
    return fd_parser_scan(p);
}
