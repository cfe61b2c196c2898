"""Secret detection and redaction (defence in depth behind the sandboxes)."""

from __future__ import annotations

from visphy_core.secrets import is_secret_name, redact, redact_obj, secret_values


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
