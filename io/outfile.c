/* outfile.c — atomic output files and "-" inputs (io.h). */
#define _GNU_SOURCE             /* copy_file_range */
#include "io/io.h"

#include <ctype.h>
#include <dirent.h>
#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* This host's name as it goes into a temporary's name: letters, digits
 * and '-' up to the first '.', at most 63 characters ("host" if none). */
static void host_tag(char *out, size_t len)
{
    char h[256] = "";
    if (gethostname(h, sizeof h - 1) != 0)
        h[0] = '\0';
    size_t k = 0;
    for (const char *c = h; *c && *c != '.' && k + 1 < len && k < 63; c++)
        if (isalnum((unsigned char)*c) || *c == '-')
            out[k++] = *c;
    out[k] = '\0';
    if (k == 0)
        snprintf(out, len, "host");
}

/* The directories a run has swept (io.h): their names, in the order
 * swept (a run writes into few: a linear search is enough). */
struct mp_sweeps {
    char **dir;
    size_t n, cap;
    long listed;
};

mp_sweeps *mp_sweeps_new(void)
{
    return calloc(1, sizeof(mp_sweeps));
}

void mp_sweeps_free(mp_sweeps *s)
{
    if (!s)
        return;
    for (size_t i = 0; i < s->n; i++)
        free(s->dir[i]);
    free(s->dir);
    free(s);
}

long mp_sweeps_listed(const mp_sweeps *s)
{
    return s ? s->listed : 0;
}

/* Is name ".<anything>.tmp.<host>.<digits>", the digits a pid of at most
 * 18 digits?  *pid gets it. */
static int stale_form(const char *name, const char *tag, long *pid)
{
    const char *t = NULL;
    for (const char *q = strstr(name, tag); q; q = strstr(q + 1, tag))
        t = q;                                   /* the last ".tmp.<host>." */
    if (name[0] != '.' || !t || t == name + 1)
        return 0;
    const char *tail = t + strlen(tag);
    if (!*tail || strspn(tail, "0123456789") != strlen(tail) || strlen(tail) > 18)
        return 0;
    *pid = atol(tail);
    return 1;
}

/* Remove from directory dir the temporaries that runs on this host left
 * when they were killed (SIGKILL, a node's OOM killer, a job's time
 * limit): any output's ".<base>.tmp.<host>.<pid>" whose process is gone.
 * Another host's temporaries (a shared file system) and live processes'
 * are left alone; a pid reused since leaves its stale file in place,
 * harmlessly. */
static void sweep_dir(const char *dir)
{
    char host[64], tag[80];
    host_tag(host, sizeof host);
    snprintf(tag, sizeof tag, ".tmp.%s.", host);
    DIR *d = opendir(dir);
    for (struct dirent *e; d && (e = readdir(d));) {
        long pid = 0;
        if (!stale_form(e->d_name, tag, &pid))
            continue;
        if (pid <= 0 || pid == (long)getpid() || kill((pid_t)pid, 0) == 0 || errno != ESRCH)
            continue;
        size_t n = strlen(dir) + strlen(e->d_name) + 1;
        char *f = malloc(n);
        if (f) {
            snprintf(f, n, "%s%s", dir, e->d_name);
            unlink(f);
            free(f);
        }
    }
    if (d)
        closedir(d);
}

int mp_out_in_place(const char *path)
{
    struct stat st;
    if (strncmp(path, "/dev/", 5) == 0 || strncmp(path, "/proc/", 6) == 0)
        return 1;
    return stat(path, &st) == 0 && (S_ISCHR(st.st_mode) || S_ISBLK(st.st_mode) ||
                                    S_ISFIFO(st.st_mode) || S_ISSOCK(st.st_mode));
}

/* The folder a temporary for path goes to, with its '/' ("./" for a bare
 * name): path's own, so rename() is atomic, or TMPDIR (else /tmp) for an
 * output written in place: beside /dev/null it would need root, and be
 * renamed over the device.  NULL when out of memory. */
static char *tmp_dir(const char *path)
{
    const char *slash = strrchr(path, '/'), *t = getenv("TMPDIR");
    if (!mp_out_in_place(path))
        return slash ? strndup(path, (size_t)(slash - path) + 1) : strdup("./");
    const char *d = t && t[0] == '/' ? t : "/tmp";
    size_t n = strlen(d) + 2;
    char *dir = malloc(n);
    if (dir)
        snprintf(dir, n, "%s/", d);
    return dir;
}

int mp_tmp_sweep(mp_sweeps *s, const char *path)
{
    if (!path || !*path || strcmp(path, "-") == 0)
        return 0;
    char *dir = tmp_dir(path);
    if (!dir)
        return 0;                    /* out of memory: a stale file stays, harmlessly */
    for (size_t i = 0; s && i < s->n; i++)
        if (strcmp(s->dir[i], dir) == 0) {
            free(dir);
            return 0;
        }
    sweep_dir(dir);
    if (!s) {
        free(dir);
        return 1;
    }
    s->listed++;
    if (s->n == s->cap) {
        size_t cap = s->cap ? 2 * s->cap : 4;
        char **d = realloc(s->dir, cap * sizeof *d);
        if (!d) {
            free(dir);               /* not remembered: swept again next time */
            return 1;
        }
        s->dir = d;
        s->cap = cap;
    }
    s->dir[s->n++] = dir;
    return 1;
}

char *mp_tmp_name(const char *path)
{
    /* "<dir>/.<base>.tmp.<host>.<pid>" (tmp_dir): hidden so a directory
     * listing during a run stays clean, host and pid so two runs writing
     * the same output do not share a temporary, and a killed run's can be
     * told stale (mp_tmp_sweep). */
    const char *slash = strrchr(path, '/'), *base = slash ? slash + 1 : path;
    char *dir = tmp_dir(path), host[64];
    if (!dir)
        return NULL;
    host_tag(host, sizeof host);
    size_t n = strlen(dir) + strlen(base) + strlen(host) + 40;
    char *t = malloc(n);
    if (t)
        snprintf(t, n, "%s.%s.tmp.%s.%ld", strcmp(dir, "./") ? dir : "", base, host,
                 (long)getpid());
    free(dir);
    return t;
}

static void reset(mp_outfile *o)
{
    mp_tmp_unregister(o->tmp_path);
    free(o->final_path);
    free(o->tmp_path);
    memset(o, 0, sizeof *o);
}

int mp_out_open(mp_outfile *o, const char *path, char *err)
{
    memset(o, 0, sizeof *o);
    if (!path || strcmp(path, "-") == 0) {
        o->fp = stdout;
        o->is_stdout = 1;
        return 0;
    }
    if (!*path) {
        snprintf(err, MP_ERRLEN, "(no name): no output file name given");
        return 1;
    }
    o->final_path = strdup(path);
    o->tmp_path = mp_tmp_name(path);
    if (!o->final_path || !o->tmp_path) {
        snprintf(err, MP_ERRLEN, "%s: out of memory", path);
        reset(o);
        return 1;
    }
    (void)mp_tmp_register(o->tmp_path);   /* before it exists: see cleanup.c */
    o->fp = fopen(o->tmp_path, "w");
    if (!o->fp) {
        snprintf(err, MP_ERRLEN, "%s: cannot create: %s", path, strerror(errno));
        reset(o);
        return 1;
    }
    return 0;
}

int mp_out_commit(mp_outfile *o, char *err)
{
    if (!o->fp) {
        snprintf(err, MP_ERRLEN, "%s: output is not open",
                 o->final_path ? o->final_path : "(output)");
        return 1;
    }
    if (o->is_stdout) {
        int bad = fflush(stdout) != 0 || ferror(stdout);
        if (bad)
            snprintf(err, MP_ERRLEN, "(stdout): write error: %s", strerror(errno));
        memset(o, 0, sizeof *o);
        return bad;
    }
    /* A full disk often shows only at flush or close: check both before
     * the temporary may replace an older good file. */
    int bad = ferror(o->fp) || fflush(o->fp) != 0;
    int e = errno;
    if (fclose(o->fp) != 0 && !bad) {
        bad = 1;
        e = errno;
    }
    o->fp = NULL;
    if (bad) {
        snprintf(err, MP_ERRLEN, "%s: write error: %s", o->final_path, strerror(e));
        unlink(o->tmp_path);
        reset(o);
        return 1;
    }
    if (mp_out_place(o->tmp_path, o->final_path, err) != 0) {
        unlink(o->tmp_path);
        reset(o);
        return 1;
    }
    reset(o);
    return 0;
}

/* in's bytes onto out (both just opened): in the kernel where it can
 * (copy_file_range: a 60 000-star root.cat, 21 MB, was 0.26 % of the
 * run's CPU, serial, through a user buffer), else through one.  1 on a
 * write error (a read error is ferror(in)'s). */
static int copy_bytes(FILE *in, FILE *out)
{
#ifdef __linux__
    int copied = 0;
    ssize_t k;
    while ((k = copy_file_range(fileno(in), NULL, fileno(out), NULL, (size_t)1 << 30, 0)) > 0)
        copied = 1;
    if (k == 0)
        return 0;
    if (copied)                 /* failed part way: no going back */
        return 1;
#endif
    char buf[65536];
    size_t n;
    int bad = 0;
    while (!bad && (n = fread(buf, 1, sizeof buf, in)) > 0)
        bad = fwrite(buf, 1, n, out) != n;
    return bad;
}

int mp_out_fits_named(const char *param, const char *path, char *err)
{
    if (!path)
        return 0;
    if (strcmp(path, "-") == 0) {
        snprintf(err, MP_ERRLEN, "%s: '-' names standard output, where a FITS file cannot go "
                 "(name a file)", param);
        return 1;
    }
    if (strchr(path, '[')) {
        snprintf(err, MP_ERRLEN, "%s: '%.200s' holds '[', which cfitsio reads as an extension or "
                 "a section: the file could not be read back by its name (name it without)",
                 param, path);
        return 1;
    }
    return 0;
}

int mp_out_place(const char *tmp, const char *path, char *err)
{
    if (!mp_out_in_place(path)) {
        if (rename(tmp, path) == 0)
            return 0;
        if (err)
            snprintf(err, MP_ERRLEN, "%s: cannot rename the temporary file into place: %s", path,
                     strerror(errno));
        return 1;
    }
    FILE *in = fopen(tmp, "rb"), *out = in ? fopen(path, "ab") : NULL;
    int bad = !in || !out || copy_bytes(in, out) || ferror(in), e = errno;
    if (out && fclose(out) != 0 && !bad) {
        bad = 1;
        e = errno;
    }
    if (in)
        fclose(in);
    unlink(tmp);
    if (bad && err)
        snprintf(err, MP_ERRLEN, "%s: cannot write into it (a device, FIFO or socket, written in "
                 "place): %s", path, strerror(e));
    return bad;
}

int mp_out_copy(const char *from, const char *to, char *err)
{
    FILE *in = fopen(from, "rb");
    if (!in) {
        snprintf(err, MP_ERRLEN, "%s: cannot open: %s", from, strerror(errno));
        return 1;
    }
    mp_outfile o;
    if (mp_out_open(&o, to, err)) {
        fclose(in);
        return 1;
    }
    int bad = copy_bytes(in, o.fp);
    int rerr = ferror(in);
    fclose(in);
    if (rerr || bad) {
        snprintf(err, MP_ERRLEN, "%s: %s error: %s", rerr ? from : to, rerr ? "read" : "write",
                 strerror(errno));
        mp_out_abort(&o);
        return 1;
    }
    return mp_out_commit(&o, err);
}

void mp_out_abort(mp_outfile *o)
{
    if (!o)
        return;
    if (o->is_stdout) {
        fflush(stdout);
        memset(o, 0, sizeof *o);
        return;
    }
    if (o->fp)
        fclose(o->fp);
    if (o->tmp_path)
        unlink(o->tmp_path);
    reset(o);
}

FILE *mp_open_input(const char *path, char *err)
{
    if (!path || strcmp(path, "-") == 0)
        return stdin;
    FILE *fp = fopen(path, "r");
    if (!fp)
        snprintf(err, MP_ERRLEN, "%s: cannot open: %s", path, strerror(errno));
    return fp;
}

void mp_close_input(FILE *fp)
{
    if (fp && fp != stdin)
        fclose(fp);
}

char *mp_name_after(const char *image, const char *ext)
{
    const char *br = strchr(image, '[');
    size_t n = br ? (size_t)(br - image) : strlen(image);
    static const char *const endings[] = {".fits", ".fit", ".fts"};
    for (int i = 0; i < 3; i++) {
        size_t e = strlen(endings[i]);
        if (n > e && strncmp(image + n - e, endings[i], e) == 0) {
            n -= e;
            break;
        }
    }
    char *s = malloc(n + strlen(ext) + 1);
    if (s) {
        memcpy(s, image, n);
        strcpy(s + n, ext);
    }
    return s;
}

/* The local file an input name reads (a cfitsio name's [extension],
 * section or copy cut: mp_fits_local_file) stat'ed into st; 0 when it
 * names none: "-", empty, INDEF, a URL but file://, a frame's own
 * extension ("[DQ]"), or no such file. */
static int input_file(const char *name, struct stat *st)
{
    char path[4096], why[MP_GUARD_LEN];
    if (!name || !name[0] || mp_fits_local_file(name, path, sizeof path, why) ||
        strcmp(path, "INDEF") == 0)
        return 0;
    return stat(path, st) == 0;
}

typedef struct {
    dev_t dev;
    ino_t ino;
    const char *name;      /* the caller's string */
} input_id;

struct mp_inputs {
    input_id *id;
    size_t n, cap;
};

mp_inputs *mp_inputs_new(void)
{
    return calloc(1, sizeof(mp_inputs));
}

void mp_inputs_free(mp_inputs *s)
{
    if (s)
        free(s->id);
    free(s);
}

int mp_inputs_add(mp_inputs *s, const char *name)
{
    struct stat st;
    if (!s)
        return 1;
    if (!input_file(name, &st))
        return 0;
    if (s->n == s->cap) {
        size_t cap = s->cap ? 2 * s->cap : 8;
        input_id *id = realloc(s->id, cap * sizeof *id);
        if (!id)
            return 1;
        s->id = id;
        s->cap = cap;
    }
    s->id[s->n++] = (input_id){st.st_dev, st.st_ino, name};
    return 0;
}

mp_inputs *mp_inputs_of(const char *const *names, size_t n)
{
    mp_inputs *s = mp_inputs_new();
    int bad = !s;
    for (size_t k = 0; k < n && !bad; k++)
        bad = mp_inputs_add(s, names[k]);
    if (bad) {
        mp_inputs_free(s);
        return NULL;
    }
    return s;
}

int mp_outputs_clear(const char *const *in, size_t nin, const char *const *out, size_t nout,
                     char *err)
{
    mp_inputs *s = mp_inputs_of(in, nin);
    if (!s) {
        snprintf(err, MP_ERRLEN, "out of memory");
        return 1;
    }
    int rc = 0;
    for (size_t k = 0; k < nout && !rc; k++)
        rc = mp_out_overwrites(s, out[k], err);
    mp_inputs_free(s);
    return rc;
}

int mp_out_overwrites(const mp_inputs *s, const char *path, char *err)
{
    struct stat so;
    if (!s || !path || !path[0] || strcmp(path, "-") == 0 || stat(path, &so) != 0)
        return 0;
    for (size_t k = 0; k < s->n; k++) {
        if (s->id[k].dev != so.st_dev || s->id[k].ino != so.st_ino)
            continue;
        if (strcmp(path, s->id[k].name) == 0)
            snprintf(err, MP_ERRLEN, "%.200s: named as an output, but it is this run's "
                     "input: a run does not write over what it reads (name another output)",
                     path);
        else
            snprintf(err, MP_ERRLEN, "%.160s: named as an output, but it is this run's "
                     "input %.160s (the same file): a run does not write over what it reads "
                     "(name another output)", path, s->id[k].name);
        return 1;
    }
    return 0;
}
