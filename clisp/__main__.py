from .app.launch import console

console()
