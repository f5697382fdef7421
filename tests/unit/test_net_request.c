/* test_net_request.c - the request decoder and state checks (server/net/request.c). */
#include <string.h>

#include "net/net.h"
#include "sq_test.h"

/* decode a NUL-terminated message with the default 64 KiB limit */
static int dec(const char *s, sq_request *r, sq_net_error *e)
{
    return sq_request_decode(s, strlen(s), 65536, r, e);
}

/* expect a refusal with the given code */
static void expect_code(const char *msg, const char *code)
{
    sq_request r;
    sq_net_error e;
    int rc = dec(msg, &r, &e);
    CHECK(rc == -1);
    if (rc == -1) {
        CHECK(e.code != NULL);
        if (e.code && strcmp(e.code, code))
            fprintf(stderr, "  message %s: code %s (%s), expected %s\n", msg, e.code, e.message,
                    code);
        CHECK(e.code && !strcmp(e.code, code));
        CHECK(e.message[0] != 0);
    }
}

SQ_TEST(net_request_hello_defaults)
{
    sq_request r;
    sq_net_error e;
    CHECK(dec("{\"type\":\"hello\"}", &r, &e) == 0);
    CHECK(r.type == SQ_REQ_HELLO);
    CHECK(r.hello.role == SQ_ROLE_CONTROL);
    CHECK(!r.hello.has_token);
    CHECK(dec("{\"type\":\"hello\",\"client\":\"t\",\"role\":\"view\",\"token\":\"x\",\"ref\":\"a1\"}",
              &r, &e) == 0);
    CHECK(r.hello.role == SQ_ROLE_VIEW);
    CHECK(r.hello.has_token && !strcmp(r.hello.token, "x"));
    CHECK(r.ref_kind == SQ_REF_STRING && !strcmp(r.ref_str, "a1"));
    CHECK(!strcmp(r.hello.client, "t"));
}

SQ_TEST(net_request_tool_fields)
{
    sq_request r;
    sq_net_error e;
    CHECK(dec("{\"type\":\"tool\",\"id\":3,\"shape\":\"grab\",\"pos\":[0.5,-1,2e-1],"
              "\"radius\":0.08,\"active\":false,\"ref\":7}", &r, &e) == 0);
    CHECK(r.type == SQ_REQ_TOOL && r.tool.id == 3);
    CHECK(r.tool.has_shape && r.tool.shape == SQ_TOOL_GRAB);
    CHECK(r.tool.has_pos);
    CHECK_NEAR(r.tool.pos[2], 0.2, 1e-15); /* exact decimal parse, only rounding */
    CHECK(r.tool.has_active && r.tool.active == 0);
    CHECK(r.ref_kind == SQ_REF_NUMBER && r.ref_num == 7);
    CHECK(dec("{\"type\":\"tool\",\"id\":0,\"shape\":\"box\",\"pos\":[0,0,0],\"size\":[1,2,3]}",
              &r, &e) == 0);
    CHECK(r.tool.has_size && r.tool.size[1] == 2);
}

SQ_TEST(net_request_set_fields)
{
    sq_request r;
    sq_net_error e;
    CHECK(dec("{\"type\":\"set\",\"body\":1,\"material\":{\"E\":1e5,\"nu\":0.3},"
              "\"operator\":\"paper\",\"damping\":{\"mass\":0.5},"
              "\"lod\":{\"mode\":\"adaptive\",\"split\":0.001,\"merge\":0.0005}}", &r, &e) == 0);
    CHECK(r.set.body == 1 && r.set.has_E && r.set.E == 1e5 && r.set.has_nu);
    CHECK(!r.set.has_density && r.set.has_operator && r.set.op == SQ_OPERATOR_PAPER);
    CHECK(r.set.has_mass && !r.set.has_stiffness);
    CHECK(r.set.has_mode && r.set.mode == SQ_LOD_ADAPTIVE && r.set.has_split);
    CHECK(dec("{\"type\":\"set\",\"operator\":\"fem\"}", &r, &e) == 0);
    CHECK(r.set.body == -1);
}

SQ_TEST(net_request_bad_inputs)
{
    /* syntax */
    expect_code("", "bad_json");
    expect_code("{", "bad_json");
    expect_code("{\"type\":\"hello\"} x", "bad_json");
    expect_code("[1,2]", "bad_json");
    expect_code("\"hello\"", "bad_json");
    expect_code("{\"type\":\"hello\",\"client\":NaN}", "bad_json");
    expect_code("{\"type\":\"tool\",\"id\":1,\"pos\":[Infinity,0,0]}", "bad_json");
    /* type */
    expect_code("{}", "bad_type");
    expect_code("{\"type\":5}", "bad_type");
    expect_code("{\"type\":\"explode\"}", "bad_type");
    /* fields */
    expect_code("{\"type\":\"hello\",\"rol\":\"view\"}", "bad_field");
    expect_code("{\"type\":\"hello\",\"role\":1}", "bad_field");
    expect_code("{\"type\":\"hello\",\"role\":\"admin\"}", "out_of_range");
    expect_code("{\"type\":\"open\"}", "bad_field");
    expect_code("{\"type\":\"open\",\"scene\":[]}", "bad_field");
    expect_code("{\"type\":\"tool\",\"id\":\"1\"}", "bad_field");
    expect_code("{\"type\":\"tool\",\"id\":1.5}", "out_of_range");
    expect_code("{\"type\":\"tool\",\"id\":256}", "out_of_range");
    expect_code("{\"type\":\"tool\",\"id\":-1}", "out_of_range");
    expect_code("{\"type\":\"tool\",\"id\":1,\"pos\":[0,0]}", "out_of_range");
    expect_code("{\"type\":\"tool\",\"id\":1,\"pos\":[0,0,\"z\"]}", "bad_field");
    expect_code("{\"type\":\"tool\",\"id\":1,\"pos\":[0,0,1e999]}", "out_of_range");
    expect_code("{\"type\":\"tool\",\"id\":1,\"pos\":[0,0,1001]}", "out_of_range");
    expect_code("{\"type\":\"tool\",\"id\":1,\"radius\":0}", "out_of_range");
    expect_code("{\"type\":\"tool\",\"id\":1,\"active\":1}", "bad_field");
    expect_code("{\"type\":\"tool\",\"id\":1,\"id\":2}", "bad_field");
    expect_code("{\"type\":\"set\"}", "bad_field");
    expect_code("{\"type\":\"set\",\"material\":{\"nu\":0.5}}", "out_of_range");
    expect_code("{\"type\":\"set\",\"material\":{\"E\":-1}}", "out_of_range");
    expect_code("{\"type\":\"set\",\"material\":{\"E\":-1e999}}", "out_of_range");
    expect_code("{\"type\":\"set\",\"material\":{\"young\":1}}", "bad_field");
    expect_code("{\"type\":\"set\",\"material\":5}", "bad_field");
    expect_code("{\"type\":\"set\",\"operator\":\"magic\"}", "out_of_range");
    expect_code("{\"type\":\"set\",\"lod\":{\"budget\":0}}", "out_of_range");
    expect_code("{\"type\":\"step\"}", "bad_field");
    expect_code("{\"type\":\"step\",\"frames\":0}", "out_of_range");
    expect_code("{\"type\":\"step\",\"frames\":1001}", "out_of_range");
    expect_code("{\"type\":\"join\",\"session\":-3}", "out_of_range");
    expect_code("{\"type\":\"pause\",\"now\":true}", "bad_field");
    expect_code("{\"type\":\"ping\",\"ref\":{}}", "bad_field");
    expect_code("{\"type\":\"subscribe\",\"stats_hz\":100}", "out_of_range");
    /* text that is not UTF-8: a lone continuation byte, a cut sequence, an overlong form,
     * a surrogate */
    expect_code("{\"type\":\"open\",\"scene\":\"\x80\"}", "bad_json");
    expect_code("{\"type\":\"open\",\"scene\":\"\xc3\"}", "bad_json");
    expect_code("{\"type\":\"open\",\"scene\":\"\xc0\xaf\"}", "bad_json");
    expect_code("{\"type\":\"open\",\"scene\":\"\xed\xa0\x80\"}", "bad_json");
    /* control characters in strings are refused */
    expect_code("{\"type\":\"open\",\"scene\":\"a\\u0001b\"}", "out_of_range");
}

SQ_TEST(net_request_utf8_accepted)
{
    sq_request r;
    sq_net_error e;
    /* 2-, 3- and 4-byte sequences */
    CHECK(dec("{\"type\":\"open\",\"scene\":\"\xc3\xa9\xe2\x82\xac\xf0\x9f\x98\x80\"}", &r, &e) == 0);
    CHECK(!strcmp(r.open.scene, "\xc3\xa9\xe2\x82\xac\xf0\x9f\x98\x80"));
}

SQ_TEST(net_request_ref_survives_errors)
{
    sq_request r;
    sq_net_error e;
    CHECK(dec("{\"type\":\"tool\",\"id\":-1,\"ref\":\"r9\"}", &r, &e) == -1);
    CHECK(r.type == SQ_REQ_TOOL);
    CHECK(r.ref_kind == SQ_REF_STRING && !strcmp(r.ref_str, "r9"));
    CHECK_CONTAINS(e.message, "tool.id");
    CHECK_CONTAINS(e.message, "-1");
}

SQ_TEST(net_request_too_large)
{
    sq_request r;
    sq_net_error e;
    const char *m = "{\"type\":\"hello\"}";
    CHECK(sq_request_decode(m, strlen(m), 8, &r, &e) == -1);
    CHECK(!strcmp(e.code, "too_large"));
    /* not NUL-terminated input: only len bytes are read */
    char buf[64];
    memcpy(buf, "{\"type\":\"ping\"}XXXX", 19);
    CHECK(sq_request_decode(buf, 15, 100, &r, &e) == 0);
    CHECK(r.type == SQ_REQ_PING);
}

SQ_TEST(net_request_state_checks)
{
    sq_request r;
    sq_net_error e;
    int ids[2] = {1, 4};
    sq_client_ctx c = {.greeted = 0, .nbodies = 2, .ntools = 2, .tool_ids = ids, .max_tools = 2};
    CHECK(dec("{\"type\":\"list_scenes\"}", &r, &e) == 0);
    CHECK(sq_request_check(&r, &c, &e) == -1 && !strcmp(e.code, "hello_required"));
    c.greeted = 1;
    CHECK(sq_request_check(&r, &c, &e) == 0);
    CHECK(dec("{\"type\":\"tool\",\"id\":1,\"pos\":[0,0,1]}", &r, &e) == 0);
    CHECK(sq_request_check(&r, &c, &e) == -1 && !strcmp(e.code, "no_session"));
    c.in_session = 1;
    CHECK(sq_request_check(&r, &c, &e) == -1 && !strcmp(e.code, "not_controller"));
    c.is_controller = 1;
    CHECK(sq_request_check(&r, &c, &e) == 0);
    CHECK(dec("{\"type\":\"tool\",\"id\":2,\"pos\":[0,0,1]}", &r, &e) == 0);
    CHECK(sq_request_check(&r, &c, &e) == -1 && !strcmp(e.code, "unknown_tool"));
    CHECK(dec("{\"type\":\"tool\",\"id\":2,\"shape\":\"sphere\",\"pos\":[0,0,1]}", &r, &e) == 0);
    CHECK(sq_request_check(&r, &c, &e) == -1 && !strcmp(e.code, "too_many_tools"));
    CHECK(dec("{\"type\":\"set\",\"body\":2,\"operator\":\"fem\"}", &r, &e) == 0);
    CHECK(sq_request_check(&r, &c, &e) == -1 && !strcmp(e.code, "unknown_body"));
    CHECK(dec("{\"type\":\"step\",\"frames\":3}", &r, &e) == 0);
    CHECK(sq_request_check(&r, &c, &e) == -1 && !strcmp(e.code, "not_lockstep"));
    c.lockstep = 1;
    CHECK(sq_request_check(&r, &c, &e) == 0);
    CHECK(dec("{\"type\":\"pause\"}", &r, &e) == 0);
    CHECK(sq_request_check(&r, &c, &e) == -1 && !strcmp(e.code, "lockstep"));
}

SQ_TEST(net_request_take_control)
{
    sq_request r;
    sq_net_error e;
    CHECK(dec("{\"type\":\"take_control\",\"ref\":4}", &r, &e) == 0);
    CHECK(r.type == SQ_REQ_TAKE_CONTROL && !r.take_control.has_token);
    CHECK(!strcmp(sq_req_name(r.type), "take_control"));
    CHECK(dec("{\"type\":\"take_control\",\"token\":\"sesame\"}", &r, &e) == 0);
    CHECK(r.take_control.has_token && !strcmp(r.take_control.token, "sesame"));
    expect_code("{\"type\":\"take_control\",\"token\":1}", "bad_field");
    expect_code("{\"type\":\"take_control\",\"role\":\"control\"}", "bad_field");
    /* it acts on the client's session: refused before open/join */
    sq_client_ctx ctx = {.greeted = 1, .max_tools = SQ_MAX_TOOLS};
    CHECK(dec("{\"type\":\"take_control\"}", &r, &e) == 0);
    CHECK(sq_request_check(&r, &ctx, &e) == -1 && !strcmp(e.code, "no_session"));
    ctx.in_session = 1;
    CHECK(sq_request_check(&r, &ctx, &e) == 0);
}

/* the ref a client gets back for a message that is not valid JSON */
static sq_request bad_ref(const char *msg, const char *code)
{
    sq_request r;
    sq_net_error e;
    CHECK(dec(msg, &r, &e) == -1);
    CHECK(e.code && !strcmp(e.code, code));
    return r;
}

SQ_TEST(net_request_ref_recovered_from_bad_json)
{
    sq_request r = bad_ref("{\"type\":\"tool\",\"ref\":\"r7\",\"id\":1,", "bad_json"); /* cut off */
    CHECK(r.ref_kind == SQ_REF_STRING && !strcmp(r.ref_str, "r7"));
    r = bad_ref("{\"ref\": 42 , \"type\": pong}", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NUMBER && r.ref_num == 42);
    r = bad_ref("{\"type\":\"ping\",\"ref\":-1.5e2} trailing", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NUMBER && r.ref_num == -150);
    r = bad_ref("{\"type\":\"set\",\"ref\":\"a\\\"b\\\\c\",,}", "bad_json"); /* escapes decoded */
    CHECK(r.ref_kind == SQ_REF_STRING && !strcmp(r.ref_str, "a\"b\\c"));
    /* not taken: a "ref" inside a string value, inside a nested object or array, as a value */
    r = bad_ref("{\"type\":\"x \\\"ref\\\": 3\",,}", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    r = bad_ref("{\"set\":{\"ref\":3},,}", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    r = bad_ref("{\"a\":[\"x\",{\"ref\":3}],,}", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    r = bad_ref("{\"client\":\"ref\",\"x\":}", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    /* unusable values: too long, non-ASCII, \u escapes, a number cut short, not a number */
    char longref[200];
    snprintf(longref, sizeof longref, "{\"ref\":\"%070d\",}", 1);
    r = bad_ref(longref, "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    r = bad_ref("{\"ref\":\"\\u0041\",}", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    r = bad_ref("{\"ref\":\"\xc3\xa9\",}", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    r = bad_ref("{\"ref\":1e999,}", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    r = bad_ref("{\"ref\":12abc}", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    r = bad_ref("{\"ref\":true,}", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    /* not an object, not JSON at all, invalid UTF-8 (ref before the bad byte still found) */
    r = bad_ref("[1, 2]", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    r = bad_ref("hello", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NULL);
    r = bad_ref("{\"ref\":9,\"client\":\"\xff\"}", "bad_json");
    CHECK(r.ref_kind == SQ_REF_NUMBER && r.ref_num == 9);
    /* a ref of the wrong type in valid JSON: the error says "ref": null */
    r = bad_ref("{\"type\":\"ping\",\"ref\":[1]}", "bad_field");
    CHECK(r.ref_kind == SQ_REF_NULL);
    /* every prefix of a message with a ref: never a crash, the ref once it is complete */
    const char *full = "{\"type\":\"tool\",\"ref\":\"k1\",\"id\":1}";
    for (size_t n = 0; n < strlen(full); n++) {
        sq_request q;
        sq_net_error e;
        CHECK(sq_request_decode(full, n, 65536, &q, &e) == -1);
        int complete = n >= strlen("{\"type\":\"tool\",\"ref\":\"k1\"");
        CHECK(complete ? q.ref_kind == SQ_REF_STRING && !strcmp(q.ref_str, "k1")
                       : q.ref_kind != SQ_REF_STRING || !strcmp(q.ref_str, "k1"));
    }
}

SQ_TEST(net_request_nu_range_as_scene_files)
{
    /* set accepts nu in [0, 0.5), the range of scene files (docs/scenes.md) */
    sq_request r;
    sq_net_error e;
    CHECK(dec("{\"type\":\"set\",\"material\":{\"nu\":0.499}}", &r, &e) == 0);
    CHECK(r.set.has_nu && r.set.nu == 0.499);
    CHECK(dec("{\"type\":\"set\",\"material\":{\"nu\":0}}", &r, &e) == 0);
    CHECK(dec("{\"type\":\"set\",\"material\":{\"nu\":0.5}}", &r, &e) == -1);
    CHECK(!strcmp(e.code, "out_of_range"));
    CHECK_CONTAINS(e.message, "set.material.nu: 0.5 is outside [0, 0.5)");
    CHECK(dec("{\"type\":\"set\",\"material\":{\"nu\":-0.1}}", &r, &e) == -1);
    CHECK_CONTAINS(e.message, "outside [0, 0.5)");
    expect_code("{\"type\":\"set\",\"material\":{\"nu\":\"0.3\"}}", "bad_field");
}

/* set.integrator and set.implicit: decoded with their values; each bad value refused with the
 * code and a message naming the field and its range */
SQ_TEST(net_request_set_integrator)
{
    sq_request r;
    sq_net_error e;
    CHECK(dec("{\"type\":\"set\",\"integrator\":\"implicit\",\"implicit\":{\"substeps\":4,\"cg_tolerance\":1e-5,"
              "\"cg_max_iterations\":300,\"preconditioner\":\"multigrid\",\"newton_iterations\":3}}",
              &r, &e) == 0);
    CHECK(r.set.has_integrator && r.set.integrator == SQ_INTEGRATOR_IMPLICIT);
    CHECK(r.set.has_substeps && r.set.implicit.substeps == 4);
    CHECK(r.set.has_tol && r.set.implicit.tol == 1e-5);
    CHECK(r.set.has_max_iter && r.set.implicit.max_iter == 300);
    CHECK(r.set.has_precond && r.set.implicit.precond == SQ_PRECOND_MULTIGRID);
    CHECK(r.set.has_newton && r.set.implicit.newton == 3);
    CHECK(dec("{\"type\":\"set\",\"integrator\":\"explicit\"}", &r, &e) == 0);
    CHECK(r.set.integrator == SQ_INTEGRATOR_EXPLICIT && !r.set.has_tol);
    static const char *const bad[][2] = {
        {"{\"type\":\"set\",\"integrator\":\"rk4\"}", "out_of_range"},
        {"{\"type\":\"set\",\"integrator\":3}", "bad_field"},
        {"{\"type\":\"set\",\"implicit\":{\"cg_tolerance\":0}}", "out_of_range"},
        {"{\"type\":\"set\",\"implicit\":{\"cg_tolerance\":-1e-6}}", "out_of_range"},
        {"{\"type\":\"set\",\"implicit\":{\"cg_tolerance\":1}}", "out_of_range"},
        {"{\"type\":\"set\",\"implicit\":{\"cg_tolerance\":1e999}}", "out_of_range"},
        {"{\"type\":\"set\",\"implicit\":{\"cg_tolerance\":\"tight\"}}", "bad_field"},
        {"{\"type\":\"set\",\"implicit\":{\"cg_max_iterations\":0}}", "out_of_range"},
        {"{\"type\":\"set\",\"implicit\":{\"cg_max_iterations\":10001}}", "out_of_range"},
        {"{\"type\":\"set\",\"implicit\":{\"cg_max_iterations\":2.5}}", "out_of_range"},
        {"{\"type\":\"set\",\"implicit\":{\"substeps\":0}}", "out_of_range"},
        {"{\"type\":\"set\",\"implicit\":{\"substeps\":65}}", "out_of_range"},
        {"{\"type\":\"set\",\"implicit\":{\"newton_iterations\":11}}", "out_of_range"},
        {"{\"type\":\"set\",\"implicit\":{\"preconditioner\":\"ilu\"}}", "out_of_range"},
        {"{\"type\":\"set\",\"implicit\":{\"warp\":1}}", "bad_field"},
        {"{\"type\":\"set\",\"implicit\":7}", "bad_field"},
    };
    for (size_t k = 0; k < sizeof bad / sizeof bad[0]; k++)
        expect_code(bad[k][0], bad[k][1]);
    CHECK(dec("{\"type\":\"set\",\"implicit\":{\"cg_tolerance\":0}}", &r, &e) == -1);
    CHECK(strstr(e.message, "cg_tolerance") != NULL);
    CHECK(dec("{\"type\":\"set\",\"implicit\":{\"cg_max_iterations\":10001}}", &r, &e) == -1);
    CHECK(strstr(e.message, "10000") != NULL);
}
