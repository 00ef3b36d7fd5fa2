#version 400 core
// Depth pass: nothing but the fixed-function depth write.
void main() {
}
