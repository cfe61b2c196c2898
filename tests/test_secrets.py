"""Secret detection and redaction (defence in depth behind the sandboxes)."""

from __future__ import annotations

from visphy_core.infra.secrets import is_secret_name, redact, redact_obj, secret_values


def test_secret_names_by_marker_and_by_explicit_list():
    assert is_secret_name("OPENAI_API_KEY") and is_secret_name("hf_token")
    assert is_secret_name("DB_PASSWORD") and is_secret_name("GOOGLE_APPLICATION_CREDENTIALS")
    assert not is_secret_name("PATH") and not is_secret_name("HOME")
    env = {"MY_VAR": "innocent-looking-value", "VISPHY_SECRET_ENV": "MY_VAR", "PATH": "/usr/bin"}
    assert secret_values(env) == {"innocent-looking-value": "MY_VAR"}


def test_short_values_are_not_secrets():
    assert secret_values({"API_KEY": "1", "OTHER_TOKEN": "abc"}) == {}


def test_redact_replaces_every_occurrence_longest_first():
    env = {"ANTHROPIC_API_KEY": "sk-ant-123456", "SHORT_KEY": "sk-ant",
           "PATH": "sk-ant-123456-not-a-secret-name"}
    text = "key=sk-ant-123456; again sk-ant-123456 and sk-ant"
    out = redact(text, env)
    assert "sk-ant" not in out
    assert out == ("key=[REDACTED:ANTHROPIC_API_KEY]; again [REDACTED:ANTHROPIC_API_KEY] and "
                   "[REDACTED:SHORT_KEY]")


def test_redact_handles_none_empty_and_regex_characters():
    env = {"X_SECRET": "a.b*c(d)+"}
    assert redact(None, env) is None and redact("", env) == ""
    assert redact("aXbYc a.b*c(d)+", env) == "aXbYc [REDACTED:X_SECRET]"


def test_redact_obj_walks_nested_structures():
    env = {"HF_TOKEN": "hf_abcdef123"}
    obj = {"logs": ["ok", "token hf_abcdef123"], "error": ("hf_abcdef123",), "n": 3,
           "hf_abcdef123": None}
    assert redact_obj(obj, env) == {"logs": ["ok", "token [REDACTED:HF_TOKEN]"],
                                    "error": ("[REDACTED:HF_TOKEN]",), "n": 3,
                                    "[REDACTED:HF_TOKEN]": None}


def test_redact_reads_the_process_environment_by_default(monkeypatch):
    monkeypatch.setenv("VISPHY_TEST_API_KEY", "live-secret-value-42")
    assert redact("x live-secret-value-42 y") == "x [REDACTED:VISPHY_TEST_API_KEY] y"


def test_credentials_are_redacted_by_their_shape_wherever_they_come_from():
    from visphy_core.infra.secrets import redact

    cases = {
        "DATABASE_URL=postgres://u:password@db/x": "postgres://[REDACTED]@db/x",
        "fetch https://tok3n@host:8080/v1/x": "https://[REDACTED]@host:8080/v1/x",
        "Authorization: Bearer abc.DEF-123_456": "Bearer [REDACTED]",
        "Authorization: Basic YWdlbnQ6cGFzcw==": "Basic [REDACTED]",
        "GET /v1?key=AIzaSyD-123&x=1": "?key=[REDACTED]&x=1",
        "openai sk-proj-" + "a" * 40: "openai [REDACTED]",
        "anthropic sk-ant-api03-" + "b" * 40: "anthropic [REDACTED]",
        "gemini AIza" + "c" * 35: "gemini [REDACTED]",
        "hub hf_" + "d" * 34: "hub [REDACTED]",
        "gh ghp_" + "e" * 36: "gh [REDACTED]",
        "aws AKIAABCDEFGHIJKLMNOP": "aws [REDACTED]",
    }
    for text, expected in cases.items():
        out = redact(text, environ={})
        assert expected in out, (text, out)
    innocent = "the ball at x=3 falls; see https://example.org/a@b is not userinfo? sk-1"
    assert redact(innocent, environ={}) == innocent
    assert redact("[REDACTED]@host", environ={}) == "[REDACTED]@host"


def test_public_config_strips_url_credentials_and_secret_values():
    from visphy_core.infra.secrets import public_config, public_url

    assert public_url("https://user:pa55@api.example/v1") == "https://api.example/v1"
    cfg = {"model": {"base_url": "http://u:p4ssw0rd@127.0.0.1:9/v1", "name": "x"},
           "argv": ["model.base_url=https://a:b3cr3t@h/v1"], "n": 3}
    out = public_config(cfg)
    assert out["model"]["base_url"] == "http://127.0.0.1:9/v1"
    assert "b3cr3t" not in str(out) and out["n"] == 3 and out["model"]["name"] == "x"


def test_dotenv_secrets_are_registered_and_redacted_without_being_looked_up(tmp_path,
                                                                            monkeypatch):
    from visphy_core.calls import keys
    from visphy_core.infra import secrets
    env = tmp_path / ".env"
    env.write_text("MY_SERVICE_TOKEN=t0ken-value-123\nPLAIN=not-a-secret-xyz\n"
                   "VISPHY_SECRET_ENV=ODD_NAME\nODD_NAME=odd-value-456\n")
    monkeypatch.setenv("VISPHY_ENV_FILE", str(env))
    monkeypatch.setattr(secrets, "_REGISTERED", {})
    keys.register_env_files()
    text = secrets.redact("t0ken-value-123 odd-value-456 not-a-secret-xyz")
    assert text == "[REDACTED:MY_SERVICE_TOKEN] [REDACTED:ODD_NAME] not-a-secret-xyz"


def test_a_bad_dotenv_is_a_user_error_naming_the_file(tmp_path, monkeypatch):
    import pytest

    from visphy_core.api.errors import UserError
    from visphy_core.calls import keys

    env = tmp_path / ".env"
    env.write_bytes(b"KEY=\xff\xfe\x00")
    monkeypatch.setenv("VISPHY_ENV_FILE", str(env))
    with pytest.raises(UserError, match=f"{env}: the .env file is not UTF-8 text"):
        keys.find_key("KEY")


def test_log_records_are_redacted_when_formatted(monkeypatch):
    import logging

    from visphy_core.infra.secrets import install_log_redaction

    previous = logging.getLogRecordFactory()
    install_log_redaction()
    try:
        record = logging.getLogger("httpx").makeRecord(
            "httpx", logging.INFO, __file__, 1, "HTTP Request: POST %s", ("http://a:pw12345@h/v1",),
            None)
        assert record.getMessage() == "HTTP Request: POST http://[REDACTED]@h/v1"
    finally:
        logging.setLogRecordFactory(previous)
