import pytest

from app.core.errors import ShaderError
from app.render.shader_source import SHADER_DIR, preprocess


def test_include_is_inlined_with_line_directives():
    src = preprocess("scene.frag")
    assert src.files == [
        "scene.frag",
        "include/variant.glsl",
        "include/projective.glsl",
        "include/lens.glsl",
        "include/video.glsl",
        "include/surface.glsl",
        "include/projector.glsl",
        "include/blend.glsl",
    ]
    lines = src.text.splitlines()
    assert lines[0].startswith("#version 400")
    assert lines[1] == "#line 2 0"
    assert "#include" not in src.text
    assert "bool projector_visible(" in src.text
    # After the include, numbering resumes in the main file (source 0) on the next line.
    main_lines = (SHADER_DIR / "scene.frag").read_text().splitlines()
    inc = next(i for i, line in enumerate(main_lines, 1) if "#include" in line)
    assert f"#line {inc + 1} 0" in lines


def test_defines_follow_the_version_and_keep_line_numbers():
    """A specialised variant: its defines come right after the version directive, and the file's
    own numbering resumes after them, so compiler messages still name the right lines."""
    plain = preprocess("scene.frag")
    src = preprocess("scene.frag", defines={"PROJECTION": 0, "EXTRA_COUNT": 3})
    lines = src.text.splitlines()
    assert lines[0].startswith("#version 400")
    assert lines[1:4] == ["#define EXTRA_COUNT 3", "#define PROJECTION 0", "#line 2 0"]
    assert src.text.replace("#define EXTRA_COUNT 3\n#define PROJECTION 0\n", "") == plain.text
    assert src.locate("0:12(5): error: x") == "scene.frag:12: error: x"


def test_compiler_messages_point_at_files():
    src = preprocess("scene.frag")
    assert src.locate("0:12(5): error: x") == "scene.frag:12: error: x"
    assert src.locate("2:40(2): error: y") == "include/projective.glsl:40: error: y"


def test_errors(tmp_path):
    (tmp_path / "a.frag").write_text('#version 330 core\n#include "missing.glsl"\n')
    with pytest.raises(ShaderError, match="missing.glsl"):
        preprocess("a.frag", root=tmp_path)
    (tmp_path / "b.glsl").write_text('#include "c.glsl"\n')
    (tmp_path / "c.glsl").write_text('#include "b.glsl"\n')
    (tmp_path / "d.frag").write_text('#version 330 core\n#include "b.glsl"\n')
    with pytest.raises(ShaderError, match="circular"):
        preprocess("d.frag", root=tmp_path)
    with pytest.raises(ShaderError, match="not found"):
        preprocess("nope.frag", root=tmp_path)


def test_every_shader_preprocesses():
    for path in SHADER_DIR.glob("*.*"):
        if path.suffix in (".vert", ".frag"):
            assert preprocess(path.name).text.startswith("#version")
