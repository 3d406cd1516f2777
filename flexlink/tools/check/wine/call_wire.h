/* The wire between flexlink's linux64 call proxy (call_proxy.c) and its win64 call server (call_server.c).
 *
 * The proxy is a Linux library that exports the FMI functions of a win64 DLL; each call it receives travels
 * over a pipe to the server, which runs under Wine, has loaded the DLL, makes the same call and sends back
 * the return value and what the DLL wrote.  The server knows no FMI signature: a request names the function,
 * the kind of its return value and each argument as a 64-bit scalar or as memory to lend (its bytes in, out or
 * both ways); the proxy, which does know the signatures, builds it.
 *
 * Every frame, both ways, is a little-endian uint64 length followed by that many bytes.
 *
 * Request:  u32 ret kind | u32 name length | name | u32 argument count | each argument: u8 kind, payload
 * Replies:  u8 'L' log message | u8 'R' result | u8 'X' an exception that ended the server | u8 'E' an error
 */
#ifndef FLEXLINK_CALL_WIRE_H
#define FLEXLINK_CALL_WIRE_H

/* the kind of a function's return value */
enum { RET_VOID = 0, RET_INT = 1, RET_POINTER = 2, RET_STRING = 3 };

/* the kind of an argument, and its payload in the request (and in the result) */
enum {
    ARG_SCALAR = 0,       /* u64 bits (an integer, a pointer the DLL gave out, or a double's bits) */
    ARG_NULL = 1,         /* a NULL pointer */
    ARG_IN = 2,           /* u64 n, n bytes: memory the DLL reads */
    ARG_OUT = 3,          /* u64 n: memory the DLL writes (result: n bytes) */
    ARG_INOUT = 4,        /* u64 n, n bytes (result: n bytes) */
    ARG_STRING = 5,       /* i64 n, n bytes: a const char * (n = -1: NULL) */
    ARG_STRINGS_IN = 6,   /* u64 count, count strings as ARG_STRING: a const char *[] */
    ARG_STRINGS_OUT = 7,  /* u64 count: a const char *[] the DLL fills (result: count strings) */
    ARG_CALLBACKS2 = 8,   /* u64 mask (1 logger, 2 allocateMemory, 4 freeMemory), u64 environment: FMI 2 callbacks */
    ARG_LOGGER3 = 9,      /* (none): FMI 3's logMessage, reporting the instanceEnvironment argument it was given */
    ARG_BINARIES_IN = 10, /* u64 count, count times (u64 n, n bytes): a const fmi3Binary [] */
    ARG_BINARIES_OUT = 11 /* u64 count, u64 index of the argument holding the sizes (result: count byte strings) */
};

#endif
