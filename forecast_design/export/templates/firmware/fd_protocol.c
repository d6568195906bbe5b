/* fd_protocol.c: see fd_protocol.h. */
#include "fd_protocol.h"

/* CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no xor-out), bytewise table */
/* entry i: i << 8 shifted through 8 rounds of the polynomial (a literal: the equivalent nested
 * macro expands to 3^8 copies per entry and took gcc 14 s); the host tests check every entry
 * against binascii.crc_hqx */
static const uint16_t fd_crc_table[256] = {
    0x0000u, 0x1021u, 0x2042u, 0x3063u, 0x4084u, 0x50A5u, 0x60C6u, 0x70E7u,
    0x8108u, 0x9129u, 0xA14Au, 0xB16Bu, 0xC18Cu, 0xD1ADu, 0xE1CEu, 0xF1EFu,
    0x1231u, 0x0210u, 0x3273u, 0x2252u, 0x52B5u, 0x4294u, 0x72F7u, 0x62D6u,
    0x9339u, 0x8318u, 0xB37Bu, 0xA35Au, 0xD3BDu, 0xC39Cu, 0xF3FFu, 0xE3DEu,
    0x2462u, 0x3443u, 0x0420u, 0x1401u, 0x64E6u, 0x74C7u, 0x44A4u, 0x5485u,
    0xA56Au, 0xB54Bu, 0x8528u, 0x9509u, 0xE5EEu, 0xF5CFu, 0xC5ACu, 0xD58Du,
    0x3653u, 0x2672u, 0x1611u, 0x0630u, 0x76D7u, 0x66F6u, 0x5695u, 0x46B4u,
    0xB75Bu, 0xA77Au, 0x9719u, 0x8738u, 0xF7DFu, 0xE7FEu, 0xD79Du, 0xC7BCu,
    0x48C4u, 0x58E5u, 0x6886u, 0x78A7u, 0x0840u, 0x1861u, 0x2802u, 0x3823u,
    0xC9CCu, 0xD9EDu, 0xE98Eu, 0xF9AFu, 0x8948u, 0x9969u, 0xA90Au, 0xB92Bu,
    0x5AF5u, 0x4AD4u, 0x7AB7u, 0x6A96u, 0x1A71u, 0x0A50u, 0x3A33u, 0x2A12u,
    0xDBFDu, 0xCBDCu, 0xFBBFu, 0xEB9Eu, 0x9B79u, 0x8B58u, 0xBB3Bu, 0xAB1Au,
    0x6CA6u, 0x7C87u, 0x4CE4u, 0x5CC5u, 0x2C22u, 0x3C03u, 0x0C60u, 0x1C41u,
    0xEDAEu, 0xFD8Fu, 0xCDECu, 0xDDCDu, 0xAD2Au, 0xBD0Bu, 0x8D68u, 0x9D49u,
    0x7E97u, 0x6EB6u, 0x5ED5u, 0x4EF4u, 0x3E13u, 0x2E32u, 0x1E51u, 0x0E70u,
    0xFF9Fu, 0xEFBEu, 0xDFDDu, 0xCFFCu, 0xBF1Bu, 0xAF3Au, 0x9F59u, 0x8F78u,
    0x9188u, 0x81A9u, 0xB1CAu, 0xA1EBu, 0xD10Cu, 0xC12Du, 0xF14Eu, 0xE16Fu,
    0x1080u, 0x00A1u, 0x30C2u, 0x20E3u, 0x5004u, 0x4025u, 0x7046u, 0x6067u,
    0x83B9u, 0x9398u, 0xA3FBu, 0xB3DAu, 0xC33Du, 0xD31Cu, 0xE37Fu, 0xF35Eu,
    0x02B1u, 0x1290u, 0x22F3u, 0x32D2u, 0x4235u, 0x5214u, 0x6277u, 0x7256u,
    0xB5EAu, 0xA5CBu, 0x95A8u, 0x8589u, 0xF56Eu, 0xE54Fu, 0xD52Cu, 0xC50Du,
    0x34E2u, 0x24C3u, 0x14A0u, 0x0481u, 0x7466u, 0x6447u, 0x5424u, 0x4405u,
    0xA7DBu, 0xB7FAu, 0x8799u, 0x97B8u, 0xE75Fu, 0xF77Eu, 0xC71Du, 0xD73Cu,
    0x26D3u, 0x36F2u, 0x0691u, 0x16B0u, 0x6657u, 0x7676u, 0x4615u, 0x5634u,
    0xD94Cu, 0xC96Du, 0xF90Eu, 0xE92Fu, 0x99C8u, 0x89E9u, 0xB98Au, 0xA9ABu,
    0x5844u, 0x4865u, 0x7806u, 0x6827u, 0x18C0u, 0x08E1u, 0x3882u, 0x28A3u,
    0xCB7Du, 0xDB5Cu, 0xEB3Fu, 0xFB1Eu, 0x8BF9u, 0x9BD8u, 0xABBBu, 0xBB9Au,
    0x4A75u, 0x5A54u, 0x6A37u, 0x7A16u, 0x0AF1u, 0x1AD0u, 0x2AB3u, 0x3A92u,
    0xFD2Eu, 0xED0Fu, 0xDD6Cu, 0xCD4Du, 0xBDAAu, 0xAD8Bu, 0x9DE8u, 0x8DC9u,
    0x7C26u, 0x6C07u, 0x5C64u, 0x4C45u, 0x3CA2u, 0x2C83u, 0x1CE0u, 0x0CC1u,
    0xEF1Fu, 0xFF3Eu, 0xCF5Du, 0xDF7Cu, 0xAF9Bu, 0xBFBAu, 0x8FD9u, 0x9FF8u,
    0x6E17u, 0x7E36u, 0x4E55u, 0x5E74u, 0x2E93u, 0x3EB2u, 0x0ED1u, 0x1EF0u
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
