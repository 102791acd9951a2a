#version 300 es
// The web viewer's GLSL dialect (WebGL 2, OpenGL ES 3.00): what the shared shader files
// (lobelight/render/shaders) need before their text, put first by
// lobelight.render.stage_sources(..., dialect=...). ES has no default precision for floats in
// the fragment stage nor for the shadow, array and integer samplers: every one is highp (the
// renderers' arithmetic is float32 throughout).
precision highp float;
precision highp int;
precision highp sampler2D;
precision highp samplerCube;
precision highp sampler2DShadow;
precision highp sampler2DArray;
precision highp isampler2D;
