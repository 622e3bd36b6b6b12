/*
 * parfile.c — reading and writing IRAF .par text:
 *   name,type,mode,value,min,max,"prompt"
 * Fields are separated by commas; a field in double quotes may hold commas,
 * with \" and \\ inside it standing for " and \.  Fields from value on are
 * optional, and an unquoted prompt is the rest of the line (IRAF).
 */
#include <errno.h>
#include <stdlib.h>
#include <string.h>

#include "params/internal.h"

#define MALFORMED "malformed line (expected name,type,mode,value,min,max,prompt)"

enum { FIELD_OK, FIELD_BAD, FIELD_NOMEM };

static int is_blank(char c) { return c == ' ' || c == '\t'; }

/* Parse the field at *sp.  On return *sp points past the separating comma,
 * or is NULL when the line ended.  The prompt (last) takes the rest of the
 * line when it is not quoted. */
static int next_field(const char **sp, int last, char **out)
{
    const char *s = *sp;
    *out = NULL;
    while (is_blank(*s))
        s++;
    if (*s == '"') {
        size_t len = 0;
        char *buf = malloc(strlen(s) + 1);
        if (!buf)
            return FIELD_NOMEM;
        for (s++; *s != '"'; s++) {
            if (*s == '\0') {
                free(buf);
                return FIELD_BAD;          /* unterminated quote */
            }
            if (*s == '\\' && (s[1] == '"' || s[1] == '\\'))
                s++;
            buf[len++] = *s;
        }
        buf[len] = '\0';
        for (s++; is_blank(*s); s++)
            ;
        if (*s == ',' && !last)
            *sp = s + 1;
        else if (*s == '\0')
            *sp = NULL;
        else {
            free(buf);
            return FIELD_BAD;              /* text after the closing quote */
        }
        *out = buf;
        return FIELD_OK;
    }
    const char *end = last ? s + strlen(s) : strchr(s, ',');
    if (!end)
        end = s + strlen(s);
    *sp = *end == ',' ? end + 1 : NULL;
    while (end > s && is_blank(end[-1]))
        end--;
    *out = strndup(s, (size_t)(end - s));
    return *out ? FIELD_OK : FIELD_NOMEM;
}

static int valid_name(const char *s)
{
    if (!((*s >= 'A' && *s <= 'Z') || (*s >= 'a' && *s <= 'z') || *s == '_'))
        return 0;
    for (s++; *s; s++)
        if (!((*s >= 'A' && *s <= 'Z') || (*s >= 'a' && *s <= 'z')
              || (*s >= '0' && *s <= '9') || *s == '_'))
            return 0;
    return 1;
}

/* Map the type field; "f" may carry IRAF's access letters (fe, fr, ...). */
static int parse_type(const char *s, mp_par_type *t)
{
    if (!strcmp(s, "b")) *t = MP_PAR_BOOL;
    else if (!strcmp(s, "i")) *t = MP_PAR_INT;
    else if (!strcmp(s, "r")) *t = MP_PAR_REAL;
    else if (!strcmp(s, "s")) *t = MP_PAR_STRING;
    else if (s[0] == 'f' && strspn(s + 1, "enrw") == strlen(s + 1)) *t = MP_PAR_FILE;
    else if (!strcmp(s, "pset")) *t = MP_PAR_PSET;
    else return 1;
    return 0;
}

const char *mpp_type_name(mp_par_type t)
{
    switch (t) {
    case MP_PAR_BOOL: return "b";
    case MP_PAR_INT: return "i";
    case MP_PAR_REAL: return "r";
    case MP_PAR_STRING: return "s";
    case MP_PAR_FILE: return "f";
    case MP_PAR_PSET: return "pset";
    }
    return "?";
}

/* Parse one non-comment line into p (fields owned by p). */
static int parse_line(const char *line, mp_par *p, char *err)
{
    char *f[7] = { NULL };
    int nf = 0, rc = 0;
    const char *s = line;
    memset(p, 0, sizeof *p);
    while (s && nf < 7) {
        int r = next_field(&s, nf == 6, &f[nf]);
        if (r == FIELD_NOMEM) {
            mpp_errf(err, "out of memory");
            rc = 1;
            goto out;
        }
        if (r == FIELD_BAD) {
            mpp_errf(err, MALFORMED);
            rc = 1;
            goto out;
        }
        nf++;
    }
    if (nf < 3 || !valid_name(f[0]) || !f[2][0] || strspn(f[2], "aqlh") != strlen(f[2])) {
        mpp_errf(err, MALFORMED);
        rc = 1;
        goto out;
    }
    if (parse_type(f[1], &p->type)) {
        mpp_errf(err, "%s: type '%s' is not supported (b, i, r, s, f or pset)", f[0], f[1]);
        rc = 1;
        goto out;
    }
    for (int i = nf; i < 7; i++)
        if (!(f[i] = strdup(""))) {
            mpp_errf(err, "out of memory");
            rc = 1;
            goto out;
        }
    p->name = f[0]; p->mode = f[2]; p->value = f[3];
    p->min = f[4]; p->max = f[5]; p->prompt = f[6];
    free(f[1]);
    return 0;
out:
    for (int i = 0; i < 7; i++)
        free(f[i]);
    memset(p, 0, sizeof *p);
    return rc;
}

static void set_task(mp_parset *ps, const char *origin)
{
    const char *b = strrchr(origin, '/');
    b = b ? b + 1 : origin;
    size_t n = strlen(b);
    if (n > 4 && !strcmp(b + n - 4, ".par"))
        n -= 4;
    if (n >= sizeof ps->task)
        n = sizeof ps->task - 1;
    memcpy(ps->task, b, n);
    ps->task[n] = '\0';
}

/* `$nargs`, a line of the CL's own that IRAF's learned (uparm) files
 * carry and no task reads (the other, the task's `mode`, is a name:
 * mp_params_load_file). */
static int cl_own(const char *s)
{
    return !strncmp(s, "$nargs", 6) && strchr(" \t,", s[6]);
}

int mpp_parse(const char *text, const char *origin, mp_parset *ps, int **lines, char *err)
{
    int *ln = NULL;
    char *line = NULL;
    int lineno = 0;
    memset(ps, 0, sizeof *ps);
    set_task(ps, origin);
    if (lines)
        *lines = NULL;
    if (!strncmp(text, "\xEF\xBB\xBF", 3))
        text += 3;                            /* UTF-8 byte-order mark */
    while (*text) {
        const char *eol = strchr(text, '\n');
        size_t len = eol ? (size_t)(eol - text) : strlen(text);
        lineno++;
        free(line);
        if (!(line = strndup(text, len)))
            goto nomem;
        text += len + (eol != NULL);
        /* Drop CR (CRLF files) and trailing blanks. */
        while (len > 0 && (line[len - 1] == '\r' || is_blank(line[len - 1])))
            line[--len] = '\0';
        const char *s = line;
        while (is_blank(*s))
            s++;
        if (*s == '\0' || *s == '#' || cl_own(s))
            continue;
        mp_par p;
        if (parse_line(s, &p, err)) {
            mpp_err_prefix(err, "%s:%d: ", origin, lineno);
            goto fail;
        }
        if (mpp_find(ps, p.name)) {
            mpp_errf(err, "%s:%d: %s: defined twice", origin, lineno, p.name);
            mpp_free_par(&p);
            goto fail;
        }
        mp_par *np = realloc(ps->p, (ps->n + 1) * sizeof *np);
        int *nl = lines ? realloc(ln, (ps->n + 1) * sizeof *nl) : NULL;
        if (np)
            ps->p = np;
        if (nl)
            ln = nl;
        if (!np || (lines && !nl)) {
            mpp_free_par(&p);
            goto nomem;
        }
        if (lines)
            ln[ps->n] = lineno;
        ps->p[ps->n++] = p;
    }
    free(line);
    if (lines)
        *lines = ln;
    return 0;
nomem:
    mpp_errf(err, "%s: out of memory", origin);
fail:
    free(line);
    free(ln);
    mp_params_free(ps);
    return 1;
}

int mp_params_parse_text(const char *text, const char *origin, mp_parset *ps, char *err)
{
    int *lines;
    if (mpp_parse(text, origin, ps, &lines, err))
        return 1;
    for (size_t i = 0; i < ps->n; i++) {
        mp_par *p = &ps->p[i];
        char *v;
        if (mpp_check_bounds(p, err) || mpp_check(p, p->value, err)) {
            mpp_err_prefix(err, "%s:%d: ", origin, lines[i]);
            goto fail;
        }
        if (!(v = mpp_normalize(p, p->value))) {
            mpp_errf(err, "%s: out of memory", origin);
            goto fail;
        }
        free(p->value);
        p->value = v;
    }
    free(lines);
    return 0;
fail:
    free(lines);
    mp_params_free(ps);
    return 1;
}

int mpp_read_file(const char *path, char **text, char *err)
{
    FILE *fp = fopen(path, "rb");
    char *buf = NULL;
    size_t len = 0, cap = 0;
    *text = NULL;
    if (!fp) {
        mpp_errf(err, "%s: cannot open: %s", path, strerror(errno));
        return 1;
    }
    for (;;) {
        if (cap - len < 4096) {
            char *nb = realloc(buf, cap + 65536);
            if (!nb) {
                mpp_errf(err, "%s: out of memory", path);
                goto fail;
            }
            buf = nb;
            cap += 65536;
        }
        size_t k = fread(buf + len, 1, cap - len - 1, fp);
        len += k;
        if (k == 0)
            break;
    }
    if (ferror(fp)) {
        mpp_errf(err, "%s: read error: %s", path, strerror(errno));
        goto fail;
    }
    if (memchr(buf, '\0', len)) {
        mpp_errf(err, "%s: not a text file", path);
        goto fail;
    }
    fclose(fp);
    buf[len] = '\0';
    *text = buf;
    return 0;
fail:
    fclose(fp);
    free(buf);
    return 1;
}

/* Write s in double quotes, escaping " and \ as the parser expects. */
static void put_quoted(const char *s, FILE *fp)
{
    fputc('"', fp);
    for (; *s; s++) {
        if (*s == '"' || *s == '\\')
            fputc('\\', fp);
        fputc(*s, fp);
    }
    fputc('"', fp);
}

/* A field that would not read back unquoted: a comma or a quote in it,
 * blanks at its ends (the parser trims them). */
static int needs_quotes(const char *s)
{
    size_t n = strlen(s);
    return n && (is_blank(s[0]) || is_blank(s[n - 1]) || strpbrk(s, ",\"\\"));
}

void mp_params_write(const mp_parset *ps, FILE *fp)
{
    for (size_t i = 0; i < ps->n; i++) {
        const mp_par *p = &ps->p[i];
        /* Strings, file names and pset file names are always quoted (IRAF
         * writes them so); numbers and booleans never need it. */
        int text = p->type == MP_PAR_STRING || p->type == MP_PAR_FILE
                   || p->type == MP_PAR_PSET;
        if (p->type == MP_PAR_PSET)
            fprintf(fp, "# parameter set %s (its parameters follow; name=value sets them too)\n",
                    p->name);
        fprintf(fp, "%s,%s,%s,", p->name, mpp_type_name(p->type), p->mode);
        if (text || needs_quotes(p->value))
            put_quoted(p->value, fp);
        else
            fputs(p->value, fp);
        fputc(',', fp);
        if ((text && p->min[0]) || needs_quotes(p->min))
            put_quoted(p->min, fp);
        else
            fputs(p->min, fp);
        fputc(',', fp);
        if ((text && p->max[0]) || needs_quotes(p->max))
            put_quoted(p->max, fp);
        else
            fputs(p->max, fp);
        fputc(',', fp);
        put_quoted(p->prompt, fp);
        fputc('\n', fp);
    }
}
