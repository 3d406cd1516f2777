/* flexlink's linux64 call proxy: how an exported FMI function (proxy_fmi2.c, proxy_fmi3.c) hands its call to
 * the win64 call server under Wine (call_proxy.c).  A function describes its arguments in order, then
 * finishes the call:
 *
 *     Call c;
 *     call_begin(&c, "fmi2GetReal", RET_INT);
 *     call_scalar(&c, pointer_bits(c_));            the component: the DLL's own pointer, passed back as it is
 *     call_in(&c, vr, nvr * sizeof *vr);            memory the DLL reads
 *     call_scalar(&c, nvr);
 *     call_out(&c, value, nvr * sizeof *value);     memory the DLL writes, copied back here
 *     return (fmi2Status)call_finish(&c);
 */
#ifndef FLEXLINK_CALL_PROXY_H
#define FLEXLINK_CALL_PROXY_H

#include <stddef.h>
#include <stdint.h>

#include "call_wire.h"

#define CALL_MAX_ARGS 16

typedef struct {
    unsigned char *data;
    size_t size, capacity;
    const char *name;
    int ret;
    uint32_t nargs;
    struct { int kind; void *target; size_t size, count, sizes_arg; } args[CALL_MAX_ARGS];
} Call;

/* the host's logger of one instance, which the server's log messages reach through their environment id */
typedef struct {
    void (*logger2)(void *, const char *, int, const char *, const char *, ...);
    void (*logger3)(void *, int, const char *, const char *);
    void *environment;
} LogRoute;

void call_begin(Call *c, const char *name, int ret);
void call_scalar(Call *c, uint64_t bits);
void call_double(Call *c, double x);
void call_in(Call *c, const void *p, size_t n);
void call_out(Call *c, void *p, size_t n);
void call_inout(Call *c, void *p, size_t n);
void call_string(Call *c, const char *s);
void call_strings_in(Call *c, const char *const *s, size_t count);
void call_strings_out(Call *c, const char **s, size_t count);
void call_binaries_in(Call *c, const size_t *sizes, const unsigned char *const *values, size_t count);
void call_binaries_out(Call *c, const unsigned char **values, size_t count, uint32_t sizes_arg);
void call_callbacks2(Call *c, uint64_t mask, uint64_t route);
void call_logger3(Call *c, int present);         /* FMI 3's logMessage: the server's own, or NULL */
uint64_t route_add(LogRoute route);             /* the id the server's log messages name the route by */
uint64_t call_finish(Call *c);

uint64_t pointer_bits(const void *p);
/* a file URI or a path of the host's, as the DLL under Wine sees it (drive Z: is the root) */
char *windows_uri(const char *uri);
char *windows_path(const char *path);

#endif
