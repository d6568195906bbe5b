/* fd_protocol.h: the board side of the framed serial protocol of docs/protocol.md (version 2):
 * sync 0xA5 0x5A, uint16 length, uint8 type, uint16 sequence, payload, CRC-16/CCITT-FALSE. */
#ifndef FD_PROTOCOL_H
#define FD_PROTOCOL_H

#include <stdint.h>

#define FD_PROTOCOL_VERSION 2u
#define FD_MAX_PAYLOAD 1024u
#define FD_HEADER_SIZE 7u

enum {
    FD_MSG_PING = 0x01, FD_MSG_UPLOAD = 0x10, FD_MSG_SET_REFERENCE = 0x11, FD_MSG_START = 0x12,
    FD_MSG_STOP = 0x13, FD_MSG_HEARTBEAT = 0x14, FD_MSG_SENSOR = 0x15,
    FD_MSG_ACK = 0x80, FD_MSG_INFO = 0x81, FD_MSG_SAMPLE = 0x90, FD_MSG_DONE = 0x91,
    FD_MSG_FAULT = 0x92, FD_MSG_STATS = 0x93
};

enum { FD_ACK_OK = 0, FD_ACK_BAD_PAYLOAD = 1, FD_ACK_NO_CONTROLLER = 2, FD_ACK_BUSY = 3, FD_ACK_UNKNOWN_TYPE = 4 };

enum {
    FD_FAULT_NONE = 0, FD_FAULT_LINK_TIMEOUT = 1, FD_FAULT_LINK_CORRUPT = 2, FD_FAULT_FRAME_DROPPED = 3,
    FD_FAULT_OVERRUN = 4, FD_FAULT_WATCHDOG_RESET = 5, FD_FAULT_ENCODER = 6,
    FD_FAULT_CONTROLLER = 7
};

uint16_t fd_crc16(const uint8_t *p, uint32_t n, uint16_t crc);

/* Incremental parser. A candidate with an unknown (or board-bound) type, a length above
 * FD_MAX_PAYLOAD or not matching a fixed-size type, or a bad CRC, is abandoned by skipping one
 * byte only, exactly like forecast_design.runtime.protocol.FrameParser. */
typedef struct {
    uint8_t buf[FD_HEADER_SIZE + FD_MAX_PAYLOAD + 2u];
    uint32_t len;
    uint32_t garbage;        /* bytes skipped since the last intact frame */
    uint32_t corrupt;        /* CRC failures, total */
    uint32_t frames;         /* intact frames, total */
    uint8_t type;            /* the frame just completed */
    uint16_t seq;
    uint16_t length;
    const uint8_t *payload;
} fd_parser;

void fd_parser_init(fd_parser *p);
/* Append one byte, then call fd_parser_next until it returns 0: each 1 is an intact frame
 * (type/seq/length/payload valid until the next call). */
void fd_parser_feed(fd_parser *p, uint8_t byte);
int fd_parser_next(fd_parser *p);

/* Encode a frame into out (FD_HEADER_SIZE + n + 2 bytes); returns its size. */
uint32_t fd_encode_frame(uint8_t *out, uint8_t type, uint16_t seq, const uint8_t *payload, uint32_t n);

void fd_put_u16(uint8_t *p, uint16_t v);
void fd_put_u32(uint8_t *p, uint32_t v);
void fd_put_f32(uint8_t *p, float v);
uint32_t fd_get_u32(const uint8_t *p);
float fd_get_f32(const uint8_t *p);

#endif /* FD_PROTOCOL_H */
